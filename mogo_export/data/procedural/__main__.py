"""`python -m mogo_export.data.procedural OUT_DIR [--clips N] [--seed S] ...`: see writer.main."""
from .writer import main

main()
