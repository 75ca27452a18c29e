"""Tracking: thin trackers orchestrating role objects (predict, gate, associate, update, initiate, delete)."""
