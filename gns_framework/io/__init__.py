"""Files the framework writes and reads back: checkpoints, rollout files, and VTK for ParaView."""
