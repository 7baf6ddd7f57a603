"""Theophylline after one oral dose (R's Theoph, bundled as
src/tensorid/datasets/theophylline.csv): one compartment with first-order absorption,
log-normal random effects on ka, cl and v.

    tensorid fit examples/theophylline/model.py src/tensorid/datasets/theophylline.csv \
        --records ID --columns t=Time,cp=conc --substeps 40

(--substeps 40: RK4's steps are per sample interval, and the last interval is twelve
hours against an absorption time of forty minutes; with the default 4 the fit warns
that its estimates are the scheme's.)

Each subject (column ID) is one unit with its own time stamps; Wt (kg) and Dose
(mg/kg) are constant per subject (covariates), read by the inputs of their names. The
dose, Dose × Wt mg, is in the depot at the first sample (Time = 0).
"""

rhs = {
    "depot": "-ka * depot",
    "center": "ka * depot - cl / v * center",
}
output = {"cp": "center / v"}  # mg/L
inputs = ["Dose", "Wt"]
params = ["ka", "cl", "v"]  # 1/h, L/h, L

covariates = ["Wt", "Dose"]  # constant within each subject: checked when read
x0 = {"depot": "Dose * Wt", "center": 0.0}  # mg, at each subject's first sample
p0 = {"ka": 1.5, "cl": 2.7, "v": 31.5}
population = {"ka": 0.6, "cl": 0.3, "v": 0.1}  # starts of ω (sd of log ka, log cl, log v)
