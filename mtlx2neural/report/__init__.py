"""Reports over an exported layer: renders of chosen views, the HTML report, shader cost."""
