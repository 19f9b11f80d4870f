"""The command line's plumbing: option types, output folders, the torch device, and running folds
and seeds as tasks (one after another, local processes or Ray)."""
