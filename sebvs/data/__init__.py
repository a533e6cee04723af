"""Recorded demonstrations: episode files (HDF5), the dataset index, and the `sebvs record` / `sebvs data` commands."""
