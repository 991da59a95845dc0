"""Motion capture: Qualisys TSV / C3D I/O, the synthetic demonstrator, marker labeling, preprocessing."""
