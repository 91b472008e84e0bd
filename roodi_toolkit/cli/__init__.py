"""The ``roodi-toolkit`` command line: parses options, calls the library, reports.

It lives inside the package, so neither the installed wheel nor the source tree has a top-level ``cli`` module that
could shadow another distribution's.
"""
