"""Tele-operation: the authenticated UDP operator link (``link``), the operator's command
sources and send loop (``operator``), its terminal UI (``tui``), a plant stand-in for the vehicle
side (``sink``) and the link's security cases (``selftest``); ``vehicle`` makes the receiver the
drive loop's command source (``controller.actuation``, ``hmpc teleop``). Imports
``hmpc.models`` and the rest of ``hmpc.controller``; never ``hmpc.tools``."""
