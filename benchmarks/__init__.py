"""mogo benchmarks (issue 6): `python -m benchmarks.run` (or `make bench`); see benchmarks/README.md."""
