"""A multiple-dose study in NONMEM's layout (benchmarks/peers/multiple_dose_nlme.R makes
it with a fixed seed): 16 subjects take 100 mg by mouth every 12 h (one dose row, II
12, ADDL 5), 8 get 100 mg IV every 24 h (ADDL 2); 16 concentrations each. One
compartment with first-order absorption; the oral doses go to the depot (CMT 1), the
IV ones to the central state (CMT 2), so the bioavailability F is estimated.

    tensorid fit examples/multiple_dose/model.py DATA.csv --records ID \
        --columns t=TIME,cp=DV
"""

rhs = {
    "depot": "-ka * depot",
    "central": "ka * depot - cl / v * central",
}
output = {"cp": "central / v"}  # mg/L
params = ["ka", "cl", "v", "F"]

doses = {"depot": "F * amt"}  # what an oral dose puts in the depot
p0 = {"ka": 1.0, "cl": 2.5, "v": 25.0, "F": 0.8}
population = {"ka": 0.3, "cl": 0.3, "v": 0.3}
