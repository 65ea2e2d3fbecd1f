# Reference values for vtexp's mixed logistic model (vtexp.analysis.glmm.mixed_logit),
# computed with lme4::glmer. Writes tests/r_reference/expected_glmer.json, which
# tests/test_glmm_reference.py compares against. R is needed only to regenerate it.
#
#   apt-get install -y r-base-core r-cran-afex r-cran-lme4
#   Rscript tests/r_reference/glmer.R          (from the repository root)
#
# It also writes tests/data/fhch2010.csv: the columns id, stimulus, frequency, item and
# correct of the data set `fhch2010` that ships with the R package afex (Freeman,
# Heathcote, Chalmers & Hockley 2010, lexical decision and naming; 98 % correct overall,
# every naming trial correct): the near-ceiling case.
#
# Fits (binomial, logit link; levels sorted, the first is the reference, as vtexp does):
# - trials_glmm: correct ~ display + timing + (1 | participant), Laplace (nAGQ = 1) and
#   adaptive Gauss-Hermite quadrature with 9 and 25 nodes.
# - fhch2010: correct ~ stimulus + frequency + (1 | id), Laplace and nAGQ = 9.
# - trials_items: correct ~ display + timing + (1 | participant) + (1 | item), Laplace.
# - fhch2010 with items: correct ~ stimulus + frequency + (1 | id) + (1 | item), Laplace.
# For each: the estimates, their standard errors (vcov(): lme4's finite-difference
# Hessian of the deviance in (theta, beta)), the random effects' SDs, the deviance
# (-2 log likelihood) and lme4's convergence messages.

suppressMessages({
  library(afex)
  library(lme4)
  library(jsonlite)
})

here <- "tests/r_reference"
data_dir <- "tests/data"
num <- function(x) unname(as.numeric(x))

data(fhch2010, package = "afex")
fh <- data.frame(id = as.character(fhch2010$id), stimulus = as.character(fhch2010$stimulus),
                 frequency = as.character(fhch2010$frequency), item = as.character(fhch2010$item),
                 correct = as.integer(fhch2010$correct))
write.csv(fh, file.path(data_dir, "fhch2010.csv"), row.names = FALSE, quote = FALSE)

read_data <- function(name, factors) {
  d <- read.csv(file.path(data_dir, paste0(name, ".csv")), colClasses = "character")
  d$correct <- as.numeric(d$correct)
  for (f in factors) d[[f]] <- factor(d[[f]], levels = sort(unique(d[[f]]), method = "radix"))
  d
}

fit <- function(name, formula, factors, nAGQ = 1) {
  d <- read_data(name, factors)
  msgs <- character(0)
  m <- withCallingHandlers(
    glmer(as.formula(formula), family = binomial, data = d, nAGQ = nAGQ),
    warning = function(w) { msgs <<- c(msgs, conditionMessage(w)); invokeRestart("muffleWarning") })
  co <- summary(m)$coefficients
  vc <- VarCorr(m)
  list(dataset = name, formula = formula, nAGQ = nAGQ, term = rownames(co),
       estimate = num(co[, "Estimate"]), se = num(co[, "Std. Error"]),
       sd = lapply(vc, function(v) num(attr(v, "stddev"))),
       deviance = num(-2 * logLik(m)), messages = c(msgs, m@optinfo$conv$lme4$messages))
}

fits <- list(
  fit("trials_glmm", "correct ~ display + timing + (1 | participant)", c("display", "timing")),
  fit("trials_glmm", "correct ~ display + timing + (1 | participant)", c("display", "timing"), 9),
  fit("trials_glmm", "correct ~ display + timing + (1 | participant)", c("display", "timing"), 25),
  fit("fhch2010", "correct ~ stimulus + frequency + (1 | id)", c("stimulus", "frequency")),
  fit("fhch2010", "correct ~ stimulus + frequency + (1 | id)", c("stimulus", "frequency"), 9),
  fit("trials_items", "correct ~ display + timing + (1 | participant) + (1 | item)",
      c("display", "timing")),
  fit("fhch2010", "correct ~ stimulus + frequency + (1 | id) + (1 | item)",
      c("stimulus", "frequency")))

result <- list(generated_by = "tests/r_reference/glmer.R", R = R.version.string,
               lme4 = as.character(packageVersion("lme4")),
               afex = as.character(packageVersion("afex")), fits = fits)
writeLines(toJSON(result, auto_unbox = TRUE, digits = NA, pretty = TRUE),
           file.path(here, "expected_glmer.json"))
cat("wrote", file.path(here, "expected_glmer.json"), "\n")
