"""HTML reports built from results files alone (arrives with the report issue)."""
