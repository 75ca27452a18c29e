"""Stateless DSP functions: numpy in, numpy out; shapes, axes and units in each docstring."""
