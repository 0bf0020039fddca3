"""geofix.nav."""
