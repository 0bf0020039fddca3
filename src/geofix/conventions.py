"""Conventions used throughout geofix: frames, angles, units and array shapes.

Frames
------
- Local metric frame: ``x`` = east, ``y`` = north, metres. Geographic (lon/lat) maps are
  projected once, when loaded, to a local transverse-Mercator frame and resampled to a
  regular metric grid; no matcher ever sees degrees.
- Grid indexing: ``values[row, col]``; row 0 is the *southern* edge, column 0 the western
  edge; the centre of cell ``[row, col]`` is ``(x0 + col * dx, y0 + row * dy)``.
- Body frame of the vehicle (sensor footprint offsets): ``(across, along)`` in metres,
  ``across`` positive to starboard, ``along`` positive forward; a third component
  ``down`` (positive down) where a vector is three-dimensional (a beam's vector from
  the sensor, a mounting offset). Such vectors are levelled by the vehicle's roll and
  pitch (:mod:`geofix.sensors.attitude`) before the heading turns them into ``(x, y)``.

Angles
------
- Heading: degrees clockwise from north at every interface a person touches (scenario
  files, CLI, settings ending in ``_deg``); radians inside the numerics.
- A heading ``psi`` moves the vehicle along ``(sin psi, cos psi)`` in ``(x, y)``.
- Roll: positive starboard side down; pitch: positive bow up (radians inside the
  numerics, ``roll`` / ``pitch`` arguments of ``Navigator.measure``; degrees in log
  tables, ``roll_deg`` / ``pitch_deg``). Body to level: ``R_y(pitch) R_x(roll)`` in
  forward-starboard-down axes; a nadir beam under a positive roll lands to port.

Fields
------
- A map stores its field as it comes: bathymetry as elevation (negative below sea level),
  gravity anomaly in mGal, magnetic anomaly in nT. ``Grid.kind`` is ``"depth"``,
  ``"gravity"`` or ``"magnetic"``;
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

#: Largest magnitude of a measured value each field kind can physically have, map units:
#: a seabed elevation within +-12 km (the deepest trench is 11 km), a free-air gravity
#: anomaly within +-1000 mGal, a magnetic reading within +-100 000 nT (the Earth's total
#: field is below 70 000 nT). Logged values beyond it are refused as poisoned.
PHYSICAL_LIMITS = {"depth": 12_000.0, "gravity": 1_000.0, "magnetic": 100_000.0}
