"""Algorithm runs for the experiment driver; importing a module registers its algorithms."""
