"""geofix.evaluate."""
