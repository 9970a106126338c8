"""The ``brdfrig`` command: one module per sub-command (parse, call one library function, print)."""
