"""`sebvs view`: a live run or a recorded episode in the rerun viewer (docs/view.md).

rerun-sdk is the optional extra `[view]`; only `sebvs.view.cli` is imported by the
command line, and it imports rerun when the command runs.
"""
