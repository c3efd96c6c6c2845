"""Driver for the real rig over a serial link, its wire protocol and a device emulator."""
