"""itc package."""
