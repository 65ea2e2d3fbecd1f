# Reference values for the confidence intervals of effect sizes (vtexp/analysis/effect_sizes.py),
# computed with R. Writes tests/r_reference/expected_effect_sizes.json, which
# tests/test_effect_sizes.py compares against. R is needed only to regenerate that file.
#
#   apt-get install -y r-base-core r-cran-afex r-cran-effectsize
#   Rscript tests/r_reference/effect_sizes.R          (from the repository root)
#
# Two computations of each interval:
# - "exact": the noncentrality found with uniroot() on R's own pf()/pt() to 1e-13 (the
#   inversion MBESS's conf.limits.ncf / conf.limits.nct do), mapped to partial eta^2 by
#   lambda / (lambda + df2) and to d_z by delta / sqrt(n). The tests compare to 1e-6.
# - "effectsize": effectsize::F_to_eta2(F, df1, df2, ci, alternative = "two.sided"),
#   effectsize::eta_squared(<afex fit>) and effectsize::cohens_d(paired = TRUE). Their
#   limits come from optim() (Nelder-Mead, abstol 1e-9 on the probabilities), so they
#   are close, not always exact: the probability pf()/pt() gives at each of effectsize's
#   limits is recorded too ("effectsize_prob"), and the tests accept a difference from
#   effectsize larger than 1e-4 only where that probability misses its target (alpha/2
#   or 1 - alpha/2) by more than 1e-4, i.e. where optim() stopped short. (F = 1.2 on 12
#   and 240 df, 95 %: effectsize's upper limit .1047 has pf = 0.0036, not 0.025.)

suppressMessages({
  library(afex)
  library(effectsize)
  library(jsonlite)
})

here <- "tests/r_reference"
data_dir <- "tests/data"
num <- function(x) unname(as.numeric(x))

ncp_f <- function(F, df1, df2, level) {
  a <- 1 - level
  g <- function(l, target) pf(F, df1, df2, ncp = l) - target
  upper_end <- function(target) {
    hi <- max(1, F * df1)
    while (g(hi, target) > 0) hi <- 2 * hi
    hi
  }
  p0 <- pf(F, df1, df2)
  root <- function(target) uniroot(g, c(0, upper_end(target)), target = target, tol = 1e-13)$root
  lo <- if (p0 > 1 - a / 2) root(1 - a / 2) else 0
  hi <- if (p0 > a / 2) root(a / 2) else 0
  c(lo, hi)
}

# pf() at the noncentrality that an eta^2 limit stands for (NA for a limit of 0)
prob_at_eta2 <- function(e, F, df1, df2) {
  ifelse(e > 0, pf(F, df1, df2, ncp = e * df2 / (1 - e)), NA)
}

eta2p_exact <- function(F, df1, df2, level) {
  l <- ncp_f(F, df1, df2, level)
  l / (l + df2)
}

dz_exact <- function(dz, n, level) {
  a <- 1 - level
  t <- dz * sqrt(n)
  g <- function(d, target) pt(t, n - 1, ncp = d) - target
  root <- function(target) {
    lo <- t - 1; hi <- t + 1
    while (g(lo, target) < 0) lo <- lo - 2 * (hi - lo)
    while (g(hi, target) > 0) hi <- hi + 2 * (hi - lo)
    uniroot(g, c(lo, hi), target = target, tol = 1e-13)$root
  }
  c(root(1 - a / 2), root(a / 2)) / sqrt(n)
}

# ---- single F and d_z values: integer and fractional (corrected) df, limits cut at 0
f_cases <- list(
  c(28.775, 1, 14), c(3.0035, 3, 33), c(3.0035 * 1, 1.37082, 15.0790), c(14.913, 2, 26),
  c(6.024, 3, 39), c(1.898, 6, 78), c(0.5, 2, 28), c(0.05, 4, 40), c(2.2, 1, 9),
  c(4.3, 2, 56), c(78.38, 1, 28), c(250, 1, 12), c(1.2, 12, 240), c(3.5, 2.7, 51.3))
eta2p <- lapply(f_cases, function(x) {
  out <- list(F = x[1], df1 = x[2], df2 = x[3])
  for (level in c(0.90, 0.95)) {
    e <- eta2p_exact(x[1], x[2], x[3], level)
    es <- F_to_eta2(x[1], x[2], x[3], ci = level, alternative = "two.sided")
    lims <- c(es$CI_low, es$CI_high)
    out[[paste0("ci", level * 100)]] <- list(exact = e, effectsize = lims,
                                             effectsize_prob = prob_at_eta2(lims, x[1], x[2], x[3]))
  }
  out
})

dz_cases <- list(c(0.8, 15), c(-0.35, 12), c(0.05, 30), c(2.4, 8), c(1.1, 5), c(-1.7, 40))
dz <- lapply(dz_cases, function(x) {
  list(dz = x[1], n = x[2], ci95 = dz_exact(x[1], x[2], 0.95))
})

# ---- whole designs: afex's F and df (sphericity assumed and Greenhouse-Geisser), the
# intervals computed from them, and effectsize::eta_squared() of the fit
read_design <- function(name, dv, factors, id) {
  d <- read.csv(file.path(data_dir, paste0(name, ".csv")), colClasses = "character")
  d[[dv]] <- as.numeric(d[[dv]])
  for (f in c(factors, id)) d[[f]] <- factor(d[[f]], levels = sort(unique(d[[f]]), method = "radix"))
  d
}

design <- function(name, dv, id, between, within) {
  d <- read_design(name, dv, c(between, within), id)
  fit <- suppressWarnings(suppressMessages(
    aov_ez(id, dv, d, between = between, within = within, fun_aggregate = mean)))
  tab <- function(corr) {
    a <- suppressWarnings(anova(fit, es = "pes", correction = corr))
    ci <- t(mapply(eta2p_exact, a$F, a[["num Df"]], a[["den Df"]],
                   MoreArgs = list(level = 0.90)))
    es <- suppressWarnings(eta_squared(a, partial = TRUE, ci = 0.90, alternative = "two.sided"))
    list(effect = rownames(a), df1 = num(a[["num Df"]]), df2 = num(a[["den Df"]]),
         F = num(a$F), pes = num(a$pes), ci90_low = num(ci[, 1]), ci90_high = num(ci[, 2]),
         effectsize_low = num(es$CI_low), effectsize_high = num(es$CI_high),
         effectsize_prob_low = num(prob_at_eta2(es$CI_low, a$F, a[["num Df"]], a[["den Df"]])),
         effectsize_prob_high = num(prob_at_eta2(es$CI_high, a$F, a[["num Df"]], a[["den Df"]])))
  }
  list(name = name, dv = dv, id = id, between = between, within = within,
       none = tab("none"), GG = if (length(within)) tab("GG") else NULL)
}

designs <- list(
  design("grid_3x4", "score", "participant", character(0), c("shape", "soa")),
  design("mixed_group_soa", "score", "participant", "group", "soa"),
  design("mixed_2b2w", "rate", "participant", c("group", "age"), c("shape", "timing")))

# ---- d_z of paired comparisons (grid_3x4, soa; each participant's mean over shape)
d <- read_design("grid_3x4", "score", c("shape", "soa"), "participant")
m <- aggregate(score ~ participant + soa, data = d, FUN = mean)
lv <- levels(d$soa)
pr <- combn(lv, 2)
pairs <- lapply(seq_len(ncol(pr)), function(j) {
  x <- m[m$soa == pr[1, j], ]; y <- m[m$soa == pr[2, j], ]
  x <- x$score[order(x$participant)]; y <- y$score[order(y$participant)]
  diff <- x - y
  v <- mean(diff) / sd(diff)
  es <- cohens_d(x, y, paired = TRUE, ci = 0.95)
  list(A = pr[1, j], B = pr[2, j], dz = v, n = length(diff),
       ci95 = dz_exact(v, length(diff), 0.95), effectsize_dz = num(es$Cohens_d),
       effectsize = c(num(es$CI_low), num(es$CI_high)),
       effectsize_prob = pt(v * sqrt(length(diff)), length(diff) - 1,
                            ncp = c(num(es$CI_low), num(es$CI_high)) * sqrt(length(diff))))
})

out <- list(
  generated_by = paste("R", R.version$major, R.version$minor, "effectsize",
                       as.character(packageVersion("effectsize")), "afex",
                       as.character(packageVersion("afex"))),
  eta2p = eta2p, dz = dz, designs = designs, pairs = list(data = "grid_3x4", factor = "soa",
                                                          rows = pairs))
writeLines(toJSON(out, auto_unbox = TRUE, digits = NA, pretty = TRUE, null = "null", na = "null"),
           file.path(here, "expected_effect_sizes.json"))
cat("wrote", file.path(here, "expected_effect_sizes.json"), "\n")
