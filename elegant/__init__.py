"""elegant package."""
