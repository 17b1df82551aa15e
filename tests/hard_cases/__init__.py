"""Hard cases: every way a run could write garbage or lose data, each with its pass criterion."""
