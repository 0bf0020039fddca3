"""geofix.sensors."""
