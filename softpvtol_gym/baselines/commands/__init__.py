"""One module per ``softpvtol`` subcommand: its options (``build_parser`` / ``_main``) and
``main(argv, layout=..., prog=...)``."""
