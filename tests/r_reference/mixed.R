# Reference values for vtexp's mixed designs (between- and within-participant factors),
# computed with R. Reads tests/data/mixed_*.csv (written by make_datasets.py) and writes
# tests/r_reference/expected_mixed.json, which tests/test_stats_mixed_reference.py
# compares against to 1e-6. R is needed only to regenerate that file.
#
#   apt-get install -y r-base-core r-cran-afex r-cran-emmeans
#   Rscript tests/r_reference/mixed.R          (from the repository root)
#
# What each block computes:
# - afex::aov_ez(id, dv, data, between = ..., within = ..., observed = ...,
#   fun_aggregate = mean): type 3 tests (afex sets contr.sum), with correction "none",
#   "GG" and "HF", anova(fit, observed = ...) for generalised eta squared, and
#   summary(fit) for the sums of squares, Mauchly's test and the epsilons.
# - simple effects, "separate": aov_ez on the data of each level of the by-factor
#   (the effect's own factors only, the others averaged).
# - simple effects, "pooled": emmeans::joint_tests(fit, by = ...) on the univariate
#   model (afex_options(emmeans_model = "univariate")), F and df2 recomputed unrounded
#   from emmeans' own objects as in rm_anova.R.
# - post hoc, pooled error: emmeans(fit, specs, by) on the univariate model, pairs()
#   with adjust = "none", "holm", "bonferroni", "fdr", "sidak".
# - post hoc, per participant: t.test(paired = TRUE) for a within factor (within each
#   group, or over all participants), t.test() (Welch) for a between factor, p.adjust.
# - trend contrasts: emmeans contrast() with the orthonormal polynomials of
#   contr.poly(k, scores) (pooled error), and t.test() of each participant's contrast
#   score (per participant).

suppressMessages({
  library(afex)
  library(emmeans)
  library(jsonlite)
})

here <- "tests/r_reference"
data_dir <- "tests/data"
num <- function(x) unname(as.numeric(x))

read_design <- function(name, dv, factors, id) {
  d <- read.csv(file.path(data_dir, paste0(name, ".csv")), colClasses = "character")
  d[[dv]] <- as.numeric(d[[dv]])
  for (f in c(factors, id)) d[[f]] <- factor(d[[f]], levels = sort(unique(d[[f]]), method = "radix"))
  d
}

fit_anova <- function(d, id, dv, between, within, observed = NULL) {
  msgs <- character(0)
  fit <- withCallingHandlers(
    aov_ez(id, dv, d, between = between, within = within, observed = observed,
           include_aov = TRUE, fun_aggregate = mean),
    warning = function(w) { msgs <<- c(msgs, conditionMessage(w)); invokeRestart("muffleWarning") },
    message = function(m) { msgs <<- c(msgs, conditionMessage(m)); invokeRestart("muffleMessage") })
  tab <- function(corr) {
    a <- suppressWarnings(anova(fit, es = c("pes", "ges"), correction = corr, observed = observed))
    list(effect = rownames(a), df1 = num(a[["num Df"]]), df2 = num(a[["den Df"]]),
         MSE = num(a$MSE), F = num(a$F), pes = num(a$pes), ges = num(a$ges),
         p = num(a[["Pr(>F)"]]))
  }
  out <- list(n = length(unique(fit$data$long[[id]])), none = tab("none"), warnings = msgs)
  if (!is.null(within)) {
    out$GG <- tab("GG")
    out$HF <- tab("HF")
    s <- suppressWarnings(summary(fit))
    uni <- s$univariate.tests
    uni <- uni[rownames(uni) != "(Intercept)", , drop = FALSE]
    out$SS <- list(effect = rownames(uni), SS = num(uni[, "Sum Sq"]), SS_error = num(uni[, "Error SS"]))
    if (!is.null(s$sphericity.tests) && length(s$sphericity.tests) > 0) {
      sp <- s$sphericity.tests
      pa <- s$pval.adjustments
      out$sphericity <- list(effect = rownames(sp), W = num(sp[, "Test statistic"]),
                             p = num(sp[, "p-value"]), eps_gg = num(pa[, "GG eps"]),
                             p_gg = num(pa[, "Pr(>F[GG])"]), eps_hf = num(pa[, "HF eps"]),
                             p_hf = num(pa[, "Pr(>F[HF])"]))
    }
  }
  list(fit = fit, out = out)
}

# emmeans:::test.emmGrid(joint = TRUE) without the final rounding (as in rm_anova.R).
joint_unrounded <- function(con, rows) {
  LL <- con@linfct[rows, , drop = FALSE]
  qrLt <- qr(t(LL))
  r <- qrLt$rank
  tQ <- t(qr.Q(qrLt))[1:r, , drop = FALSE]
  z <- tQ %*% con@bhat
  zcov <- tQ %*% con@V %*% t(tQ)
  F <- sum(z * solve(zcov, z)) / r
  df2 <- min(apply(tQ, 1, function(k) con@dffun(k, con@dfargs)))
  c(df1 = r, df2 = df2, F = F, p = pf(F, r, df2, lower.tail = FALSE))
}

pooled_simple <- function(fit, effect, by) {
  afex_options(emmeans_model = "univariate")
  on.exit(afex_options(emmeans_model = "multivariate"))
  jt <- as.data.frame(joint_tests(fit, by = by))
  emm <- emmeans(fit, specs = effect, by = by)
  con <- contrast(emm, "poly")
  res <- list()
  for (lv in levels(fit$data$long[[by]])) {
    u <- joint_unrounded(con, which(con@grid[[by]] == lv))
    j <- jt[jt[["model term"]] == effect & jt[[by]] == lv, ]
    stopifnot(nrow(j) == 1, abs(round(u[["F"]], 3) - j$F.ratio) < 1e-9,
              abs(round(u[["df2"]], 2) - j$df2) < 1e-9, abs(u[["p"]] - j$p.value) < 1e-12)
    res[[length(res) + 1]] <- list(by = lv, effect = effect, df1 = u[["df1"]], df2 = u[["df2"]],
                                   F = u[["F"]], p = u[["p"]])
  }
  res
}

separate_simple <- function(d, id, dv, between, within, effect, by) {
  res <- list()
  for (lv in levels(d[[by]])) {
    sub <- droplevels(d[d[[by]] == lv, ])
    b <- if (effect %in% between) effect else NULL
    w <- if (effect %in% within) effect else NULL
    f <- fit_anova(sub, id, dv, b, w)
    res[[length(res) + 1]] <- c(list(by = lv), f$out)
  }
  res
}

pooled_pairs <- function(fit, factor, by) {
  afex_options(emmeans_model = "univariate")
  on.exit(afex_options(emmeans_model = "multivariate"))
  emm <- if (is.null(by)) emmeans(fit, specs = factor) else emmeans(fit, specs = factor, by = by)
  base <- as.data.frame(summary(pairs(emm, adjust = "none"), infer = c(TRUE, TRUE)))
  out <- list(factor = factor, by = by, contrast = as.character(base$contrast),
              estimate = num(base$estimate), se = num(base$SE), df = num(base$df),
              t = num(base$t.ratio), p = num(base$p.value), ci_low = num(base$lower.CL),
              ci_high = num(base$upper.CL))
  if (!is.null(by)) out$by_level <- as.character(base[[by]])
  for (adj in c("holm", "bonferroni", "fdr", "sidak")) {
    out[[paste0("p_", adj)]] <- num(as.data.frame(pairs(emm, adjust = adj))$p.value)
  }
  out
}

# per-participant means of dv at each level of `cols` (the other factors averaged)
participant_means <- function(d, id, dv, cols) {
  m <- aggregate(d[[dv]], by = d[c(id, cols)], FUN = mean)
  names(m)[ncol(m)] <- dv
  m
}

paired_pairs <- function(d, id, dv, group, factor, between_factor) {
  # comparisons of `factor`'s levels within each level of `group` (NULL: all participants)
  cols <- unique(c(factor, group))
  m <- participant_means(d, id, dv, cols)
  blocks <- if (is.null(group)) list(m) else split(m, m[[group]], drop = TRUE)
  res <- list()
  for (bi in seq_along(blocks)) {
    b <- blocks[[bi]]
    bn <- names(blocks)[bi]
    lv <- levels(d[[factor]])
    pr <- combn(lv, 2)
    rows <- lapply(seq_len(ncol(pr)), function(j) {
      x <- b[b[[factor]] == pr[1, j], ]; y <- b[b[[factor]] == pr[2, j], ]
      if (between_factor) {
        t <- t.test(x[[dv]], y[[dv]])
      } else {
        x <- x[order(x[[id]]), dv]; y <- y[order(y[[id]]), dv]
        t <- t.test(x, y, paired = TRUE)
      }
      list(A = pr[1, j], B = pr[2, j], t = num(t$statistic), df = num(t$parameter),
           p = t$p.value, ci_low = t$conf.int[1], ci_high = t$conf.int[2])
    })
    p <- sapply(rows, function(r) r$p)
    for (adj in c("holm", "bonferroni", "BH")) {
      pa <- p.adjust(p, adj)
      for (j in seq_along(rows)) rows[[j]][[paste0("p_", adj)]] <- pa[j]
    }
    for (j in seq_along(rows)) rows[[j]]$group <- if (is.null(group)) NA else bn
    res <- c(res, rows)
  }
  res
}

trend <- function(fit, d, id, dv, factor, by, scores) {
  k <- length(levels(d[[factor]]))
  P <- contr.poly(k, scores = scores)
  colnames(P) <- c("linear", "quadratic", "cubic", "quartic")[seq_len(ncol(P))]
  afex_options(emmeans_model = "univariate")
  emm <- emmeans(fit, specs = factor, by = by)
  con <- as.data.frame(contrast(emm, method = as.data.frame(P)))
  afex_options(emmeans_model = "multivariate")
  pooled <- list(contrast = as.character(con$contrast), by_level = as.character(con[[by]]),
                 estimate = num(con$estimate), se = num(con$SE), df = num(con$df),
                 t = num(con$t.ratio), p = num(con$p.value))
  m <- participant_means(d, id, dv, unique(c(factor, by)))
  paired <- list()
  for (g in levels(d[[by]])) {
    b <- m[m[[by]] == g, ]
    w <- reshape(b[c(id, factor, dv)], idvar = id, timevar = factor, direction = "wide")
    Y <- as.matrix(w[, paste0(dv, ".", levels(d[[factor]]))])
    for (j in seq_len(ncol(P))) {
      s <- Y %*% P[, j]
      t <- t.test(s)
      paired[[length(paired) + 1]] <- list(by_level = g, contrast = colnames(P)[j],
                                           estimate = num(mean(s)), t = num(t$statistic),
                                           df = num(t$parameter), p = t$p.value)
    }
  }
  list(factor = factor, by = by, scores = scores, coefficients = unname(P),
       pooled = pooled, paired = paired)
}

result <- list(
  generated_by = "tests/r_reference/mixed.R",
  R = R.version.string,
  afex = as.character(packageVersion("afex")),
  emmeans = as.character(packageVersion("emmeans")),
  car = as.character(packageVersion("car")),
  datasets = list())

# --- group (between, 7 vs 9) x soa (within, 4 graded levels)
d <- read_design("mixed_group_soa", "score", c("group", "soa"), "participant")
f <- fit_anova(d, "participant", "score", "group", "soa")
e <- c(list(dv = "score", between = "group", within = "soa", subject = "participant"), f$out)
e$between_only <- fit_anova(d, "participant", "score", "group", NULL)$out
e$simple <- list(
  list(effect = "soa", by = "group",
       separate = separate_simple(d, "participant", "score", "group", "soa", "soa", "group"),
       pooled = pooled_simple(f$fit, "soa", "group")),
  list(effect = "group", by = "soa",
       separate = separate_simple(d, "participant", "score", "group", "soa", "group", "soa"),
       pooled = pooled_simple(f$fit, "group", "soa")))
e$posthoc_pooled <- list(pooled_pairs(f$fit, "soa", "group"), pooled_pairs(f$fit, "group", "soa"),
                         pooled_pairs(f$fit, "soa", NULL))
e$posthoc_paired <- list(
  list(factor = "soa", by = "group", rows = paired_pairs(d, "participant", "score", "group", "soa", FALSE)),
  list(factor = "soa", by = NULL, rows = paired_pairs(d, "participant", "score", NULL, "soa", FALSE)),
  list(factor = "group", by = "soa", rows = paired_pairs(d, "participant", "score", "soa", "group", TRUE)))
e$trend <- list(trend(f$fit, d, "participant", "score", "soa", "group", c(100, 200, 300, 400)),
                trend(f$fit, d, "participant", "score", "soa", "group", c(100, 200, 300, 600)))
result$datasets$mixed_group_soa <- e

# --- group (2) x age (3, observed) between x shape (2) x timing (3) within, one missing value
d <- read_design("mixed_2b2w", "rate", c("group", "age", "shape", "timing"), "participant")
f <- fit_anova(d, "participant", "rate", c("group", "age"), c("shape", "timing"), observed = "age")
e <- c(list(dv = "rate", between = c("group", "age"), within = c("shape", "timing"),
            observed = "age", subject = "participant"), f$out)
e$no_observed <- fit_anova(d, "participant", "rate", c("group", "age"), c("shape", "timing"))$out$none
e$simple <- list(
  list(effect = "timing", by = "group",
       separate = separate_simple(d, "participant", "rate", c("group", "age"), c("shape", "timing"),
                                  "timing", "group"),
       pooled = pooled_simple(f$fit, "timing", "group")))
e$posthoc_pooled <- list(pooled_pairs(f$fit, "timing", "group"), pooled_pairs(f$fit, "age", NULL))
result$datasets$mixed_2b2w <- e

writeLines(toJSON(result, auto_unbox = TRUE, digits = NA, pretty = TRUE, na = "null"),
           file.path(here, "expected_mixed.json"))
cat("wrote", file.path(here, "expected_mixed.json"), "\n")
