"""Traffic safety analysis on road-user tracks: traffic conflicts and surrogate safety
measures (TTC, PET, Time-to-Accident, conflicting speed, MaxS, DeltaS, deceleration),
with error intervals where the poses carry their uncertainty.

Runs on tracks alone (no ground truth): ``tracks`` reads them, ``kinematics`` estimates motion,
``footprints`` holds the rectangle geometry, ``encounters`` the spatial pre-filter, ``ttc`` and
``pet`` the indicators, ``conflicts`` the table, ``intervals`` the error bars. Imports only
seg2pose's core, io and say level code (never the network or training).
"""
