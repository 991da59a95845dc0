from besdrake.cli import main

raise SystemExit(main())
