"""Training VoRTX: crops from rendered rooms, losses, the two-phase loop and its CLI."""
