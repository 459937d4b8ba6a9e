"""Synthetic takes with ground truth: seeded marker and footage scenarios, the sample's generator and
the cross-character realism benchmark."""
