"""Utilities: argument parsing and one-line errors (``args``), optional extras (``extras``), atomic writes
(``atomic``), locks (``locks``), paths and output layouts (``paths``), generated Markdown blocks (``blocks``),
environment variables for child processes only (``environment``)."""
