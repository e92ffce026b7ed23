"""Paper reproduction and speed benchmarks."""
