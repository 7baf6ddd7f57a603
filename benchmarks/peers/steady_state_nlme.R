# A steady-state study (NONMEM's SS = 1) simulated with a fixed seed and fitted by R's
# nlme with the closed-form steady state of one compartment: the peer of
# benchmarks/bench_events.py. 16 subjects take 100 mg by mouth every 12 h and 8 get
# 100 mg IV every 24 h, each long enough to be at steady state when the record starts:
# one SS = 1 dose row at 0 with its II and ADDL 1 (the next dose, which keeps the
# steady state), then a dosing interval of samples and one after the next dose.
# Writes the NONMEM-style table (argument 1) and prints nlme's estimates as one line
# of JSON (one_compartment_nlme.R fits).
#   Rscript benchmarks/peers/steady_state_nlme.R /tmp/ss.csv
# one_compartment_nlme.R, beside this file: the fit and its line of JSON
here <- sub("^--file=", "", grep("^--file=", commandArgs(FALSE), value = TRUE))
source(file.path(dirname(normalizePath(here)), "one_compartment_nlme.R"))
args <- commandArgs(trailingOnly = TRUE)
out <- if (length(args)) args[1] else "steady_state.csv"
set.seed(20261207)
ka <- 1.2; cl <- 3.0; v <- 30; F <- 0.7
om <- c(0.3, 0.25, 0.2); sigma <- 0.1
oral_times <- c(0.25, 0.5, 1, 2, 3, 4, 6, 8, 10, 11.75, 12.5)
iv_times <- c(0.25, 1, 2, 4, 8, 12, 16, 23.5, 24.5)
# the concentration tau after a dose given every ii for ever (superposition of the
# geometric series of past doses, one compartment)
conc_ss <- function(tau, ii, amt, oral, ka, cl, v, F) {
  k <- cl / v
  if (oral) F * amt * ka / (v * (ka - k)) *
    (exp(-k * tau) / (1 - exp(-k * ii)) - exp(-ka * tau) / (1 - exp(-ka * ii)))
  else amt / v * exp(-k * tau) / (1 - exp(-k * ii))
}
rows <- list(); who <- list()
for (i in 1:24) {
  oral <- i <= 16
  eta <- rnorm(3) * om
  p <- c(ka, cl, v) * exp(eta)
  ii <- if (oral) 12 else 24
  times <- if (oral) oral_times else iv_times
  c <- conc_ss(times %% ii, ii, 100, oral, p[1], p[2], p[3], F)
  y <- c + sigma * rnorm(length(c))
  who[[i]] <- data.frame(ID = i, ii = ii, oral = oral)
  rows[[length(rows) + 1]] <- data.frame(ID = i, TIME = 0, AMT = 100, DV = ".", EVID = 1,
    MDV = 1, CMT = if (oral) 1 else 2, II = ii, ADDL = 1, SS = 1)
  rows[[length(rows) + 1]] <- data.frame(ID = i, TIME = times, AMT = ".",
    DV = sprintf("%.4f", y), EVID = 0, MDV = 0, CMT = 2, II = 0, ADDL = 0, SS = 0)
}
tab <- do.call(rbind, rows)
write.csv(tab, out, row.names = FALSE, quote = FALSE)
who <- do.call(rbind, who)
obs <- subset(tab, EVID == 0)
obs$DV <- as.numeric(obs$DV); obs$ID <- factor(obs$ID, levels = 1:24)
model <- function(TIME, ID, lka, lcl, lv, lF) {
  w <- who[as.integer(as.character(ID)), ]
  out <- numeric(length(TIME))
  for (j in seq_along(TIME)) {
    out[j] <- conc_ss(TIME[j] %% w$ii[j], w$ii[j], 100, w$oral[j], exp(lka[j]),
                      exp(lcl[j]), exp(lv[j]), exp(lF[j]))
  }
  out
}
fit_and_print(obs, model)
