"""geofix.filters."""
