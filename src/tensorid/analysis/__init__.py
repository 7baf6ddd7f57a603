"""Analysis: what a fit's estimate can be trusted with: standard errors (uncertainty,
sandwich), profiles, residual tests, data sensitivity, the model check, scores on
new records, and the tables and figures of a fit. Each function takes a fit's result;
nothing here runs a fit of its own beyond small inner solves (tensorid.solve)."""
