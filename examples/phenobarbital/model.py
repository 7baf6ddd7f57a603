"""Phenobarbital in 59 preterm neonates (R's nlme::Phenobarb, bundled as
src/tensorid/datasets/phenobarbital.csv in NONMEM's layout): repeated intravenous
doses (AMT, µg/kg) and 155 concentrations (DV, µg/mL) over up to 16 days; one
compartment, log-normal random effects on clearance and volume (both per kg).

    tensorid fit examples/phenobarbital/model.py src/tensorid/datasets/phenobarbital.csv \
        --records ID --columns t=TIME,conc=DV

The doses are the table's rows (EVID 1, CMT 1: the central state), not the model
file's: each subject's clock starts at its first dose.
"""

rhs = {"central": "-cl / v * central"}
output = {"conc": "central / v"}  # µg/kg over L/kg: mg/L = µg/mL
params = ["cl", "v"]  # L/h/kg, L/kg

x0 = {"central": 0.0}
p0 = {"cl": 0.005, "v": 1.0}
population = {"cl": 0.4, "v": 0.4}  # starts of ω (sd of log cl, log v)
