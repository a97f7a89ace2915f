"""Statistical checks of a material's sampling: chi-square goodness of fit and sampling efficiency."""
