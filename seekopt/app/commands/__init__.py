"""The ``seekopt`` commands, one module each (``cmd_<name>(args) -> exit status``).

:mod:`~seekopt.app.commands.common` holds what every command shares (the one-line input error with
exit status 2, the stage log, checks of arguments and output paths); :mod:`~seekopt.app.commands.inputs`
reads the inputs several commands share (logs, plant and controller, families, drift).  The parser and
the dispatcher are :mod:`seekopt.app.cli`.
"""
