"""CAN bridge to a robot (python-can): the config section, the frame table, the bus side."""
