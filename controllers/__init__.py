"""controllers (coming in later issues)."""
