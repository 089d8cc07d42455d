"""How the computation runs on its device: precision, allocator, host synchronisation and activation memory."""
