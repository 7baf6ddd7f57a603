"""The time discretisation (above modelling/): the Runge-Kutta schemes (tableau.py,
integrators.py, implicit.py, adaptive.py), how a record is discretised and the march
across its sample grid (discretisation.py), the input between samples
(intersample.py), and how a run ended (status.py: the integrators' failure codes)."""
