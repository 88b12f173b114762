"""What people look at: route maps (PNG, matplotlib) and live mission tables (rich)."""
