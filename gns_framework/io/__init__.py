"""Writers of simulation output for other tools (VTK for ParaView)."""
