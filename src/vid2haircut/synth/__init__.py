"""Synthetic data: procedural hairstyles, head/hair motion and sequence synthesis (benchmark side)."""
