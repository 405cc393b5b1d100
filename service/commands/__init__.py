"""``asrmap`` subcommands, one module each.

A command module defines ``NAME`` (the subcommand), ``HELP`` (one line), ``EXAMPLE`` (a command
line shown in its ``--help``), ``add_arguments(parser)`` and ``run(args) -> int`` (the exit
status). :mod:`service.cli` discovers the modules in this package; a command is thin: it parses,
calls the library, and prints.
"""
