"""Command-line entry points; `python -m drake_scenes` runs `drake_scenes.cli.__main__`."""
