# nlme's own fit of its Phenobarb data (one compartment, IV doses, log-normal random
# effects on clearance and volume, ML): the peer of benchmarks/bench_events.py.
# Prints one line of JSON.   Rscript benchmarks/peers/phenobarbital_nlme.R
suppressMessages(library(nlme))
t0 <- proc.time()
fit <- nlme(conc ~ phenoModel(Subject, time, dose, lCl, lV), data = Phenobarb,
            fixed = lCl + lV ~ 1, random = pdDiag(lCl + lV ~ 1), start = c(-5, 0),
            na.action = na.pass, naPattern = ~ !is.na(conc), method = "ML")
el <- (proc.time() - t0)[["elapsed"]]
tt <- summary(fit)$tTable
sd <- as.numeric(VarCorr(fit)[1:2, "StdDev"])
cat(sprintf(paste0('{"seconds": %.3f, "m2ll": %.4f, "log_cl": [%.6f, %.6f], ',
  '"log_v": [%.6f, %.6f], "omega": [%.5f, %.5f], "sigma": %.5f}\n'),
  el, -2 * as.numeric(logLik(fit)), tt[1, 1], tt[1, 2], tt[2, 1], tt[2, 2], sd[1], sd[2],
  fit$sigma))
