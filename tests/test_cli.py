from besdrake.cli import build_parser, main


def test_help_lists_no_duplicate_commands(capsys):
    parser = build_parser()
    assert parser.prog == "besdrake"
    assert main([]) == 2
    out = capsys.readouterr().out
    assert "usage: besdrake" in out
