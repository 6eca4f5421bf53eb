"""Tele-operation: the authenticated UDP operator link (``link``), the operator's command
sources and send loop (``operator``), its terminal UI (``tui``), a plant stand-in for the vehicle
side (``sink``) and the link's security cases (``selftest``); ``hmpc teleop`` hosts the receiver
in the drive loop (``controller.actuation``). Imports ``hmpc.models`` and the rest of
``hmpc.controller``; never ``hmpc.tools``."""
