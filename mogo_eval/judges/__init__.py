"""The judge models evaluation trains and trusts: an action classifier and text-motion evaluators."""
