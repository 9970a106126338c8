"""What people look at: BRDF plots and the self-contained HTML report of a fit or session."""
