"""File formats the built-in dataset layouts read and write: not components themselves."""
