"""The ERP transformer policies: model, inputs, dataset loader, training, checkpoints and inference."""
