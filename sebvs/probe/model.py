"""The probe's model: a small CNN with a localisation head and a visibility head.

    net = ProbeNet(in_channels=2)               # the event frame's ON, OFF counts
    centre, logit = net(x)                      # x [B, C, 160, 160] -> [B, 2] in [0, 1], [B]

Four convolutions (5x5 stride 2, then 3x3 stride 2, 3x3 stride 2, 3x3 stride 1; 16, 32, 32,
32 channels, ReLU; receptive field 33 px at 160 px input) give a 20 x 20 feature map at
160 px. Localisation: a 1x1 convolution makes one score per cell, a softmax over the cells
weighs the cell centres (a soft arg-max), so the centre is a fraction of the input's width
and height and cannot leave the image. Visibility: one linear unit on the features' mean
and max over the map and the scores' log-sum-exp. The same model for every sensor and
cell; only the input channels differ (rgb 3, event 2, both 5).
"""
from __future__ import annotations

import torch
from torch import nn


class ProbeNet(nn.Module):
    def __init__(self, in_channels: int, width: int = 32, batchnorm: bool = False):
        super().__init__()
        layers, channels = [], in_channels
        for out, k, stride in ((width // 2, 5, 2), (width, 3, 2), (width, 3, 2), (width, 3, 1)):
            layers.append(nn.Conv2d(channels, out, k, stride=stride, padding=k // 2))
            if batchnorm:
                layers.append(nn.BatchNorm2d(out))
            layers.append(nn.ReLU())
            channels = out
        self.features = nn.Sequential(*layers)
        self.score = nn.Conv2d(width, 1, 1)
        self.visible = nn.Linear(2 * width + 1, 1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x [B, C, H, W] -> (centre [B, 2] as fractions (u / W, v / H), visibility logit
        [B])."""
        return self.heads(x)[:2]

    def heads(self, x: torch.Tensor):
        """(centre, visibility logit, the cells' scores [B, h, w])."""
        f = self.features(x)
        b, _, h, w = f.shape
        scores = self.score(f).flatten(1)                         # [B, h w]
        weights = torch.softmax(scores, dim=1)
        ys, xs = torch.meshgrid((torch.arange(h, dtype=f.dtype, device=f.device) + 0.5) / h,
                                (torch.arange(w, dtype=f.dtype, device=f.device) + 0.5) / w,
                                indexing="ij")
        centre = torch.stack([weights @ xs.reshape(-1), weights @ ys.reshape(-1)], dim=1)
        pooled = torch.cat([f.mean(dim=(2, 3)), f.amax(dim=(2, 3)),
                            torch.logsumexp(scores, dim=1, keepdim=True)], dim=1)
        return centre, self.visible(pooled).squeeze(1), scores.reshape(b, h, w)
