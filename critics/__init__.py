"""critics package."""
