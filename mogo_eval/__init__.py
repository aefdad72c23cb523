"""Evaluation of mogo: judge models, metrics and reports. Never imported by the product (mogo_export,
mogo_runtime); it imports them."""
