"""geofix.match."""
