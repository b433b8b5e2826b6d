"""What a fit is made of: objective (priors, robust losses), problem, identifiability, diagnostics, result."""
