# A multiple-dose study (oral and IV, II/ADDL) simulated with a fixed seed and fitted
# by R's nlme with a closed-form superposition model: the peer of
# benchmarks/bench_events.py. Writes the NONMEM-style table (argument 1) and prints
# nlme's estimates as one line of JSON.
#   Rscript benchmarks/peers/multiple_dose_nlme.R /tmp/md.csv
# one_compartment_nlme.R, beside this file: the fit and its line of JSON
here <- sub("^--file=", "", grep("^--file=", commandArgs(FALSE), value = TRUE))
source(file.path(dirname(normalizePath(here)), "one_compartment_nlme.R"))
args <- commandArgs(trailingOnly = TRUE)
out <- if (length(args)) args[1] else "multiple_dose.csv"
set.seed(20261206)
ka <- 1.2; cl <- 3.0; v <- 30; F <- 0.7
om <- c(0.3, 0.25, 0.2); sigma <- 0.15
times <- c(0.5, 1, 2, 4, 8, 12, 24, 36, 48, 60.5, 61, 62, 64, 68, 72, 84)
# the concentration at t after doses at td (superposition, one compartment)
conc1 <- function(t, td, amt, oral, ka, cl, v, F) {
  k <- cl / v; tau <- pmax(t - td, 0); on <- t > td
  if (oral) sum(on * F * amt * ka / (v * (ka - k)) * (exp(-k * tau) - exp(-ka * tau)))
  else sum(on * amt / v * exp(-k * tau))
}
rows <- list(); doses <- list()
for (i in 1:24) {
  oral <- i <= 16
  eta <- rnorm(3) * om
  p <- c(ka, cl, v) * exp(eta)
  ii <- if (oral) 12 else 24; addl <- if (oral) 5 else 2
  td <- seq(0, by = ii, length.out = addl + 1)
  doses[[i]] <- data.frame(ID = i, td = td, amt = 100, oral = oral)
  c <- sapply(times, function(t) conc1(t, td, 100, oral, p[1], p[2], p[3], F))
  y <- c + sigma * rnorm(length(c))
  rows[[length(rows) + 1]] <- data.frame(ID = i, TIME = 0, AMT = 100, DV = ".", EVID = 1,
    MDV = 1, CMT = if (oral) 1 else 2, II = ii, ADDL = addl)
  rows[[length(rows) + 1]] <- data.frame(ID = i, TIME = times, AMT = ".", DV = sprintf("%.4f", y),
    EVID = 0, MDV = 0, CMT = 2, II = 0, ADDL = 0)
}
tab <- do.call(rbind, rows)
write.csv(tab, out, row.names = FALSE, quote = FALSE)
dosetab <- do.call(rbind, doses)
obs <- subset(tab, EVID == 0)
obs$DV <- as.numeric(obs$DV); obs$ID <- factor(obs$ID, levels = 1:24)
model <- function(TIME, ID, lka, lcl, lv, lF) {
  out <- numeric(length(TIME))
  for (j in seq_along(TIME)) {
    d <- dosetab[dosetab$ID == as.integer(as.character(ID[j])), ]
    out[j] <- conc1(TIME[j], d$td, d$amt, d$oral[1], exp(lka[j]), exp(lcl[j]), exp(lv[j]),
                    exp(lF[j]))
  }
  out
}
fit_and_print(obs, model)
