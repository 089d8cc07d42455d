"""Built-in ground-truth simulators."""
