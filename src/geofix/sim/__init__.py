"""geofix.sim."""
