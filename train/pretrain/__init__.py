"""Contrastive pretraining of the offline backbone on rendered crops of training-split objects."""
