"""The ``roodi-toolkit`` command line: parses options, calls the library, reports. Installed as roodi_toolkit.cli."""
