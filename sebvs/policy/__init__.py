"""The ERP transformer policies: model, inputs, dataset loader, training, checkpoints and inference.

    from sebvs.policy.train import train
    train("datasets/nav", "ck", "nav", ["rgb", "rgb+event"])   # ck/nav-rgb.pt + .json, ...
    from sebvs.policy.infer import PolicySet, resolve_checkpoints
    policies = PolicySet(resolve_checkpoints({}, "ck", "nav", ["rgb", "rgb+event"]))

docs/policy.md.
"""
