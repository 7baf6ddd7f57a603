# What the simulated studies' peers share (multiple_dose_nlme.R, steady_state_nlme.R):
# nlme's fit of a one-compartment model with random ka, cl and v and a shared F, all on
# the log scale, by maximum likelihood, and its estimates printed as one line of JSON.
suppressMessages(library(nlme))

fit_and_print <- function(obs, model) {
  t0 <- proc.time()
  fit <- nlme(DV ~ model(TIME, ID, lka, lcl, lv, lF), data = obs,
              fixed = lka + lcl + lv + lF ~ 1, random = pdDiag(lka + lcl + lv ~ 1),
              groups = ~ID, start = c(log(1), log(2.5), log(25), log(0.8)), method = "ML")
  el <- (proc.time() - t0)[["elapsed"]]
  tt <- summary(fit)$tTable
  sd <- as.numeric(VarCorr(fit)[1:3, "StdDev"])
  cat(sprintf(paste0('{"seconds": %.3f, "m2ll": %.4f, "log_ka": [%.6f, %.6f], ',
    '"log_cl": [%.6f, %.6f], "log_v": [%.6f, %.6f], "log_F": [%.6f, %.6f], ',
    '"omega": [%.5f, %.5f, %.5f], "sigma": %.5f}\n'),
    el, -2 * as.numeric(logLik(fit)), tt[1, 1], tt[1, 2], tt[2, 1], tt[2, 2], tt[3, 1],
    tt[3, 2], tt[4, 1], tt[4, 2], sd[1], sd[2], sd[3], fit$sigma))
}

