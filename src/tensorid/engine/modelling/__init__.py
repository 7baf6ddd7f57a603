"""What the user describes (above compiling/): the model (model.py) or its text
equations (equations.py), the measured records (data.py) with their events
(events.py) and initial states (initial.py), a fleet's kinds of parameter (fleet.py),
the checks of all of it (checks.py), and the fit metrics (metrics.py). Nothing here
integrates anything."""
