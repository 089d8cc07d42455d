"""Ground truth: scene specs, simulators and dataset generation."""
