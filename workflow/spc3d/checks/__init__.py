"""Checks of what a user asks for, beyond the schema: settings against each other and against the
rows that use them (``crosscheck``), and the targets named on the command line (``targets``)."""
