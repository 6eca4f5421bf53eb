"""CAN actuation: profiles (params/*.actuation.yaml), one pure frame builder per message,
safety limits checked twice, the vehicle simulator node and the real-time drive loop (the only
owner of a ``can.Bus``) with its parts: the feedback it decodes, the command path, injected
faults, the candump and its audit, the run's summary. Imports ``hmpc.models`` and the rest of
``hmpc.controller``; never ``hmpc.tools``."""
