"""Conventions used throughout geofix: frames, angles, units and array shapes.

Frames
------
- Local metric frame: ``x`` = east, ``y`` = north, metres. Geographic (lon/lat) maps are
  projected once, when loaded, to a local transverse-Mercator frame and resampled to a
  regular metric grid; no matcher ever sees degrees.
- Grid indexing: ``values[row, col]``; row 0 is the *southern* edge, column 0 the western
  edge; the centre of cell ``[row, col]`` is ``(x0 + col * dx, y0 + row * dy)``.
- Body frame of the vehicle (sensor footprint offsets): ``(across, along)`` in metres,
  ``across`` positive to starboard, ``along`` positive forward.

Angles
------
- Heading: degrees clockwise from north at every interface a person touches (scenario
  files, CLI, settings ending in ``_deg``); radians inside the numerics.
- A heading ``psi`` moves the vehicle along ``(sin psi, cos psi)`` in ``(x, y)``.

Fields
------
- A map stores its field as it comes: bathymetry as elevation (negative below sea level),
  gravity anomaly in mGal. ``Grid.kind`` is ``"depth"`` or ``"gravity"``;
  ``Grid.units`` says the unit.

Shapes
------
- A track is ``(n, 2)`` positions in metres, one row per sample.
- Measurements are ``(n, b)``: ``n`` samples by ``b`` beams (``b = 1`` for single-beam and
  gravimeter), NaN for a missing value.
- Sensor footprint offsets are ``(b, 2)`` body-frame ``(across, along)`` metres.

Randomness
----------
- Every random draw takes an explicit :class:`numpy.random.Generator`; there is no global
  random state. A scenario carries its seed; trial ``i`` uses
  ``numpy.random.default_rng([seed, i])``.

Units
-----
- SI unless the name says otherwise: ``gyro_bias_deg_h`` (deg/h), ``accel_bias_ug``
  (micro-g), ``gyro_noise_deg_rt_h`` (deg/sqrt(h)), ``accel_noise_ug_rt_hz``
  (micro-g/sqrt(Hz)).
"""
