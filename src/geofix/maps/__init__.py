"""geofix.maps."""
