"""The operator's view of a campaign: a live local web page, safe-point controls, a printer console."""
