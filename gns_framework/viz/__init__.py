"""Pictures for people: animations of rollouts beside their ground truth."""
