# R's nlme on the bundled theophylline copy (the same file tensorid reads): one
# compartment, first-order absorption, log-normal random effects on ka, cl and v
# (diagonal), additive error, ML; the dose is Dose (mg/kg) x Wt. The peer of
# benchmarks/bench_theophylline.py. Prints one line of JSON.
#   Rscript benchmarks/peers/theophylline_nlme.R src/tensorid/datasets/theophylline.csv
suppressMessages(library(nlme))
args <- commandArgs(trailingOnly = TRUE)
d <- read.csv(args[1])
d$amt <- d$Dose * d$Wt
d <- groupedData(conc ~ Time | ID, data = d)
cp <- function(amt, t, lka, lcl, lv) {
  ka <- exp(lka); ke <- exp(lcl - lv); v <- exp(lv)
  amt * ka / (v * (ka - ke)) * (exp(-ke * t) - exp(-ka * t))
}
t0 <- proc.time()
fit <- nlme(conc ~ cp(amt, Time, lka, lcl, lv), data = d,
            fixed = lka + lcl + lv ~ 1, random = pdDiag(lka + lcl + lv ~ 1),
            start = c(log(1.5), log(2.7), log(31.5)), method = "ML")
el <- (proc.time() - t0)[["elapsed"]]
fe <- fixef(fit)
sd <- as.numeric(VarCorr(fit)[1:3, "StdDev"])
cat(sprintf(paste0('{"seconds": %.3f, "m2ll": %.4f, "ka": %.5f, "cl": %.5f, "v": %.5f, ',
  '"omega": [%.5f, %.5f, %.5f], "sigma": %.5f}\n'),
  el, -2 * as.numeric(logLik(fit)), exp(fe[[1]]), exp(fe[[2]]), exp(fe[[3]]),
  sd[1], sd[2], sd[3], fit$sigma))
