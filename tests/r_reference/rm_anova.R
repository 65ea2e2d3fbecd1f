# Reference values for vtexp's statistics, computed with R.
#
# Reads the datasets in tests/data/ (written by make_datasets.py) and writes
# tests/r_reference/expected.json, which tests/test_stats_r_reference.py compares
# against to 1e-6. R is needed only to regenerate that file, not to run the tests.
#
#   apt-get install -y r-base-core r-cran-afex r-cran-emmeans   (Debian)
#   Rscript tests/r_reference/rm_anova.R          (from the repository root)
#
# What each block computes:
# - afex::aov_ez(id, dv, data, within = ..., fun_aggregate = mean): the ANOVA with
#   correction "none", "GG" and "HF" (num Df, den Df, MSE, F, pes, ges, p), and
#   summary(fit): Sum Sq / Error SS, Mauchly's test, GG and HF epsilon and p.
# - simple effects, "separate": aov_ez on the data of each level of the by-factor,
#   the other factors averaged (fun_aggregate = mean).
# - simple effects, "pooled": emmeans::joint_tests(fit, by = ...) with
#   afex_options(emmeans_model = "univariate") on an include_aov = TRUE fit.
#   joint_tests rounds F to 3 decimals and df2 to 2 (it prints them so), so the
#   unrounded values are recomputed below with the same emmeans objects and the
#   same lines as emmeans:::test.emmGrid(joint = TRUE); the script stops if they
#   disagree with joint_tests' own rounded F and df2 or with its (unrounded) p.
# - post hoc: t.test(paired = TRUE) for each pair of levels of a factor (the other
#   factors averaged per participant), p.adjust("holm") and ("bonferroni"),
#   Cohen's d_z = mean(diff) / sd(diff).
# - ordinal: friedman.test and wilcox.test(paired = TRUE, correct = TRUE).
# - trial-level model: lme4::glmer(correct ~ display + timing + (1 | participant),
#   family = binomial) (Laplace), the frequentist fit that vtexp's Bayesian
#   statsmodels fit is compared with (loosely: a different estimator).

suppressMessages({
  library(afex)
  library(emmeans)
  library(jsonlite)
})

here <- "tests/r_reference"
data_dir <- "tests/data"
stopifnot(file.exists(file.path(data_dir, "seed000_2x2.csv")))

read_data <- function(name) {
  d <- read.csv(file.path(data_dir, paste0(name, ".csv")), colClasses = "character")
  d
}

as_factors <- function(d, within, id) {
  for (f in c(within, id)) d[[f]] <- factor(d[[f]], levels = sort(unique(d[[f]]), method = "radix"))
  d
}

num <- function(x) unname(as.numeric(x))

anova_block <- function(d, id, dv, within) {
  msgs <- character(0)
  fit <- withCallingHandlers(
    aov_ez(id, dv, d, within = within, include_aov = TRUE, fun_aggregate = mean),
    warning = function(w) { msgs <<- c(msgs, conditionMessage(w)); invokeRestart("muffleWarning") },
    message = function(m) { msgs <<- c(msgs, conditionMessage(m)); invokeRestart("muffleMessage") })
  tab <- function(corr) {
    a <- suppressWarnings(anova(fit, es = c("pes", "ges"), correction = corr))
    list(effect = rownames(a), df1 = num(a[["num Df"]]), df2 = num(a[["den Df"]]),
         MSE = num(a$MSE), F = num(a$F), pes = num(a$pes), ges = num(a$ges),
         p = num(a[["Pr(>F)"]]))
  }
  s <- suppressWarnings(summary(fit))
  uni <- s$univariate.tests
  uni <- uni[rownames(uni) != "(Intercept)", , drop = FALSE]
  out <- list(
    n = length(unique(fit$data$long[[id]])),
    none = tab("none"), GG = tab("GG"), HF = tab("HF"),
    SS = list(effect = rownames(uni), SS = num(uni[, "Sum Sq"]), SS_error = num(uni[, "Error SS"])),
    warnings = msgs)
  if (!is.null(s$sphericity.tests) && length(s$sphericity.tests) > 0) {
    sp <- s$sphericity.tests
    pa <- s$pval.adjustments
    out$sphericity <- list(effect = rownames(sp), W = num(sp[, "Test statistic"]),
                           p = num(sp[, "p-value"]), eps_gg = num(pa[, "GG eps"]),
                           p_gg = num(pa[, "Pr(>F[GG])"]), eps_hf = num(pa[, "HF eps"]),
                           p_hf = num(pa[, "Pr(>F[HF])"]))
  }
  list(fit = fit, out = out)
}

# emmeans:::test.emmGrid(joint = TRUE) without the final rounding, for one by-group.
joint_unrounded <- function(con, rows) {
  LL <- con@linfct[rows, , drop = FALSE]
  bhat <- con@bhat
  qrLt <- qr(t(LL))
  r <- qrLt$rank
  tR <- t(qr.R(qrLt))[1:r, 1:r, drop = FALSE]
  tQ <- t(qr.Q(qrLt))[1:r, , drop = FALSE]
  z <- tQ %*% bhat
  zcov <- tQ %*% con@V %*% t(tQ)
  F <- sum(z * solve(zcov, z)) / r
  df2 <- min(apply(tQ, 1, function(k) con@dffun(k, con@dfargs)))
  c(df1 = r, df2 = df2, F = F, p = pf(F, r, df2, lower.tail = FALSE))
}

pooled_block <- function(fit, effect, by) {
  afex_options(emmeans_model = "univariate")
  on.exit(afex_options(emmeans_model = "multivariate"))
  jt <- as.data.frame(joint_tests(fit, by = by))
  terms <- unlist(lapply(seq_along(effect), function(r) combn(effect, r, paste, collapse = ":")))
  res <- list()
  for (term in terms) {
    tf <- strsplit(term, ":")[[1]]
    emm <- emmeans(fit, specs = tf, by = by)
    con <- if (length(tf) == 1) contrast(emm, "poly") else contrast(emm, interaction = "poly")
    grid <- con@grid
    for (lv in levels(fit$data$long[[by]])) {
      rows <- which(grid[[by]] == lv)
      u <- joint_unrounded(con, rows)
      j <- jt[jt[["model term"]] == term & jt[[by]] == lv, ]
      stopifnot(nrow(j) == 1, abs(round(u[["F"]], 3) - j$F.ratio) < 1e-9,
                abs(round(u[["df2"]], 2) - j$df2) < 1e-9, abs(u[["p"]] - j$p.value) < 1e-12)
      res[[length(res) + 1]] <- list(by = lv, effect = term, df1 = u[["df1"]], df2 = u[["df2"]],
                                     F = u[["F"]], p = u[["p"]],
                                     joint_tests_F = j$F.ratio, joint_tests_df2 = j$df2)
    }
  }
  res
}

separate_block <- function(d, id, dv, within, effect, by) {
  res <- list()
  for (lv in levels(d[[by]])) {
    sub <- droplevels(d[d[[by]] == lv, ])
    b <- anova_block(sub, id, dv, effect)
    b$out$by <- lv
    res[[length(res) + 1]] <- b$out
  }
  res
}

posthoc_block <- function(d, id, dv, factor) {
  d[[dv]] <- as.numeric(d[[dv]])
  m <- aggregate(d[[dv]], by = list(id = d[[id]], lv = d[[factor]]), FUN = mean)
  w <- reshape(m, idvar = "id", timevar = "lv", direction = "wide")
  w <- w[order(w$id), ]
  lv <- levels(d[[factor]])
  pairs <- combn(lv, 2)
  rows <- lapply(seq_len(ncol(pairs)), function(j) {
    a <- w[[paste0("x.", pairs[1, j])]]; b <- w[[paste0("x.", pairs[2, j])]]
    t <- t.test(a, b, paired = TRUE)
    list(A = pairs[1, j], B = pairs[2, j], mean_diff = mean(a - b), t = num(t$statistic),
         df = num(t$parameter), p = t$p.value, dz = mean(a - b) / sd(a - b),
         ci_low = t$conf.int[1], ci_high = t$conf.int[2])
  })
  p <- sapply(rows, function(r) r$p)
  holm <- p.adjust(p, "holm"); bonf <- p.adjust(p, "bonferroni")
  for (j in seq_along(rows)) { rows[[j]]$p_holm <- holm[j]; rows[[j]]$p_bonferroni <- bonf[j] }
  rows
}

ordinal_block <- function(d, id, dv, factor) {
  d[[dv]] <- as.numeric(d[[dv]])
  fr <- friedman.test(as.formula(paste(dv, "~", factor, "|", id)), data = d)
  lv <- levels(d[[factor]])
  pairs <- combn(lv, 2)
  wil <- lapply(seq_len(ncol(pairs)), function(j) {
    a <- d[d[[factor]] == pairs[1, j], ]; a <- a[order(a[[id]]), dv]
    b <- d[d[[factor]] == pairs[2, j], ]; b <- b[order(b[[id]]), dv]
    t <- suppressWarnings(wilcox.test(a, b, paired = TRUE, correct = TRUE))
    list(A = pairs[1, j], B = pairs[2, j], V = num(t$statistic), p = t$p.value)
  })
  p <- sapply(wil, function(r) r$p)
  holm <- p.adjust(p, "holm")
  for (j in seq_along(wil)) wil[[j]]$p_holm <- holm[j]
  list(friedman = list(statistic = num(fr$statistic), df = num(fr$parameter), p = fr$p.value),
       wilcoxon = wil)
}

designs <- list(
  oneway_sphericity = list(id = "participant", dv = "rt", within = c("soa")),
  seed000_2x2 = list(id = "participant", dv = "rate", within = c("timing", "intensity"),
                     simple = list(effect = "intensity", by = "timing"), posthoc = "timing"),
  grid_3x4 = list(id = "participant", dv = "score", within = c("shape", "soa"),
                  simple = list(effect = "soa", by = "shape"), posthoc = "soa"),
  threeway = list(id = "participant", dv = "rate", within = c("display", "timing", "intensity"),
                  simple = list(effect = c("timing", "intensity"), by = "display")),
  missing_cell = list(id = "participant", dv = "correct", within = c("shape", "timing"),
                      simple = list(effect = "timing", by = "shape"))
)

result <- list(
  generated_by = "tests/r_reference/rm_anova.R",
  R = R.version.string,
  afex = as.character(packageVersion("afex")),
  emmeans = as.character(packageVersion("emmeans")),
  car = as.character(packageVersion("car")),
  datasets = list())

for (name in names(designs)) {
  spec <- designs[[name]]
  d <- as_factors(read_data(name), spec$within, spec$id)
  d[[spec$dv]] <- as.numeric(d[[spec$dv]])
  b <- anova_block(d, spec$id, spec$dv, spec$within)
  entry <- c(list(dv = spec$dv, within = spec$within, subject = spec$id), b$out)
  if (!is.null(spec$simple)) {
    entry$simple <- list(effect = spec$simple$effect, by = spec$simple$by,
      separate = separate_block(d, spec$id, spec$dv, spec$within, spec$simple$effect, spec$simple$by),
      pooled = pooled_block(b$fit, spec$simple$effect, spec$simple$by))
  }
  if (!is.null(spec$posthoc)) {
    entry$posthoc <- list(factor = spec$posthoc, rows = posthoc_block(d, spec$id, spec$dv, spec$posthoc))
  }
  result$datasets[[name]] <- entry
}

r <- as_factors(read_data("ratings"), "frequency", "participant")
result$ordinal <- c(list(dataset = "ratings", dv = "rating", factor = "frequency", subject = "participant"),
                    ordinal_block(r, "participant", "rating", "frequency"))

g <- read_data("trials_glmm")
g$correct <- as.numeric(g$correct)
g$display <- factor(g$display, levels = c("static", "dynamic"))
g$timing <- factor(g$timing, levels = c("fixed", "slow", "varied"))
gm <- lme4::glmer(correct ~ display + timing + (1 | participant), family = binomial, data = g)
co <- summary(gm)$coefficients
result$glmer <- list(dataset = "trials_glmm", term = rownames(co), estimate = num(co[, "Estimate"]),
                     se = num(co[, "Std. Error"]),
                     sd_participant = num(attr(lme4::VarCorr(gm)$participant, "stddev")),
                     lme4 = as.character(packageVersion("lme4")))

writeLines(toJSON(result, auto_unbox = TRUE, digits = NA, pretty = TRUE),
           file.path(here, "expected.json"))
cat("wrote", file.path(here, "expected.json"), "\n")
