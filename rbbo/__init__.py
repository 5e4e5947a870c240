"""rbbo (coming in later issues)."""
