"""geofix.plot."""
