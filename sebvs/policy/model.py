"""The ERP transformer (paper section 3.4): early-fused RGB + event frames -> an action.

    model = ERP("nav", in_channels=5, size=160)     # rgb+event; stem="patch", the paper's
    y = model(x)          # x float32 [B, 5, 160, 160] from inputs.py -> [B, 2]: [v, w]

x [B, C, S, S] (C = 3 rgb | 2 event | 5 rgb+event) -> PatchEmbedding, tokens [B, N, 64]
with N = (S/16)^2 (100 at 160 px, 1600 at 640 px; ConvStem gives the same tokens) ->
class token prepended, fixed 2-D sinusoidal positions added [B, 1+N, 64] -> one pre-norm
encoder layer (4-head self-attention, 256-unit MLP, dropout 0.1) -> the task head on the
class token: nav [v, w] in [-1, 1], arm a 6-DoF pose.

The variants differ only in the patch embedding's input channels (``in_channels``); every
other size is a constructor argument with the paper's value as default. Our departures,
off by default, are the stems: ``stem="conv"`` (ConvStem) and, for rgb+event only,
``stem="gated"`` (GatedFusionStem: a stem per modality and a learned gate in place of
early fusion) and its control ``stem="dual"`` (DualStem: the two stems, no gate).
docs/policy.md, "Model" and "Training".
"""
from __future__ import annotations

import math

import torch
from torch import nn

TASK_OUTPUTS = {"nav": 2, "arm": 6}


def sinusoidal_positions_2d(rows: int, cols: int, dim: int) -> torch.Tensor:
    """Fixed 2-D sinusoidal encoding, [rows*cols, dim], row-major like the patch order.

    Half of the channels encode the patch row, half the column, each with the usual
    1-D sin/cos ladder (Vaswani et al.) over dim/4 frequencies: a 2-D grid keeps the
    vertical neighbourhood that a flattened 1-D index would scatter.
    """
    if dim % 4:
        raise ValueError(f"embedding dim {dim} must be divisible by 4 for 2-D positions")
    quarter = dim // 4
    freq = torch.exp(-math.log(10000.0) * torch.arange(quarter, dtype=torch.float64) / quarter)

    def ladder(n: int) -> torch.Tensor:                       # [n, dim/2]
        angle = torch.arange(n, dtype=torch.float64)[:, None] * freq[None, :]
        return torch.cat([angle.sin(), angle.cos()], dim=1)

    r, c = ladder(rows), ladder(cols)
    grid = torch.cat([r[:, None, :].expand(rows, cols, dim // 2),
                      c[None, :, :].expand(rows, cols, dim // 2)], dim=2)
    return grid.reshape(rows * cols, dim).float()


class PatchEmbedding(nn.Module):
    """Non-overlapping patches -> tokens: [B, C, S, S] -> [B, (S/p)^2, dim].

    A Conv2d with kernel = stride = patch is exactly "flatten each patch and project it".
    """

    def __init__(self, in_channels: int, dim: int = 64, patch: int = 16):
        super().__init__()
        self.patch = patch
        self.proj = nn.Conv2d(in_channels, dim, kernel_size=patch, stride=patch)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(x).flatten(2).transpose(1, 2)


class ConvStem(nn.Module):
    """Early convolutions in place of the linear patchify: [B, C, S, S] -> [B, (S/p)^2, dim].

    log2(p) 3x3 stride-2 convolutions (BatchNorm + ReLU between them, widths doubling up to
    ``dim``), the last one projecting to ``dim``: the same grid of tokens as
    PatchEmbedding, each seeing its patch and a margin around it through a nonlinear
    filter bank. Xiao et al. (2021, "Early convolutions help transformers see better")
    found this stem steadies ViT training; we use it where the paper's one-layer model
    underfits (the arm's pose: its yaw and sub-patch position are not linear in a patch's
    pixels; docs/policy.md).
    """

    def __init__(self, in_channels: int, dim: int = 64, patch: int = 16):
        super().__init__()
        n = patch.bit_length() - 1
        if patch < 4 or 1 << n != patch:
            raise ValueError(f"the conv stem needs a power-of-two patch >= 4, got {patch}")
        layers, c = [], in_channels
        for i in range(n - 1):
            w = max(8, dim >> (n - 2 - i))
            layers += [nn.Conv2d(c, w, 3, stride=2, padding=1, bias=False),
                       nn.BatchNorm2d(w), nn.ReLU(inplace=True)]
            c = w
        layers.append(nn.Conv2d(c, dim, 3, stride=2, padding=1))
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x).flatten(2).transpose(1, 2)


RGB_PLANES = 3      # an rgb+event input's first planes (inputs.py); the rest are events


class DualStem(nn.Module):
    """RGB and event planes through conv stems of their own, the tokens summed:
    [B, 3 + E, S, S] -> [B, (S/p)^2, dim].

        tokens = ConvStem(x[:, :3]) + ConvStem(x[:, 3:])

    The control for GatedFusionStem: the same two stems without the gate, so a study can
    tell what the gate adds from what a stem per modality adds.
    """

    def __init__(self, in_channels: int, dim: int = 64, patch: int = 16):
        super().__init__()
        events = in_channels - RGB_PLANES
        if events < 2 or events % 2:
            raise ValueError(f"the {type(self).__name__} fuses 3 rgb planes with 2K event "
                             f"planes (modality rgb+event), got {in_channels} input channels")
        self.rgb = ConvStem(RGB_PLANES, dim, patch)
        self.events = ConvStem(events, dim, patch)

    def streams(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x [B, 3 + E, S, S] -> (rgb tokens, event tokens), each [B, N, dim]."""
        return self.rgb(x[:, :RGB_PLANES]), self.events(x[:, RGB_PLANES:])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        rgb, events = self.streams(x)
        return rgb + events


class GatedFusionStem(DualStem):
    """RGB and event planes through stems of their own, the event tokens added to the RGB
    ones through a learned gate: [B, 3 + E, S, S] -> [B, (S/p)^2, dim].

        rgb    = ConvStem(x[:, :3])                           [B, N, dim]
        events = ConvStem(x[:, 3:])                           [B, N, dim]
        gate   = sigmoid(Linear([rgb, events]))               [B, N, dim]
        tokens = rgb + gate * events

    Early fusion (one stem over all planes) mixes the two in the first convolution, so a
    patch of floor that moves under a turn, and fires as many events as the target, looks
    to every later layer like one input. Here each patch's RGB and event content is read
    apart and the gate, seeing both, can let the events through where they add something
    (a moving target in a dark or blurred image) and hold them back where they are
    ego-motion. The gate starts half open (bias 0). Issue 15, item 3.
    """

    def __init__(self, in_channels: int, dim: int = 64, patch: int = 16):
        super().__init__(in_channels, dim, patch)
        self.gate = nn.Linear(2 * dim, dim)
        nn.init.zeros_(self.gate.bias)

    def gates(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """x [B, 3 + E, S, S] -> (rgb tokens, event tokens, gate), each [B, N, dim]."""
        rgb, events = self.streams(x)
        return rgb, events, torch.sigmoid(self.gate(torch.cat([rgb, events], dim=2)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        rgb, events, gate = self.gates(x)
        return rgb + gate * events


STEMS = {"patch": PatchEmbedding, "conv": ConvStem, "dual": DualStem,
         "gated": GatedFusionStem}
# what carries a policy's state from one control tick to the next: nothing (the paper's
# per-tick model) or a GRU cell over the encoded class tokens (RecurrentState)
MEMORIES = ("none", "gru")


class TokenSequence(nn.Module):
    """Prepends the learnable class token and adds fixed positions: [B, N, D] -> [B, 1+N, D].

    The positional table is a non-persistent buffer built for the model's grid: it is not
    in the state_dict (it is a function of the size in the config, not a weight). The class
    token gets no positional term, as in ViT.
    """

    def __init__(self, grid: int, dim: int = 64):
        super().__init__()
        self.cls = nn.Parameter(torch.zeros(1, 1, dim))
        nn.init.trunc_normal_(self.cls, std=0.02)
        self.register_buffer("pos", sinusoidal_positions_2d(grid, grid, dim)[None],
                             persistent=False)

    def forward(self, tokens: torch.Tensor) -> torch.Tensor:
        cls = self.cls.expand(tokens.shape[0], -1, -1)
        return torch.cat([cls, tokens + self.pos], dim=1)


class NavHead(nn.Module):
    """PolicyHeadNav: class token [B, D] -> [v, w] [B, 2], squashed to [-1, 1] by tanh."""

    def __init__(self, dim: int = 64, hidden: int = 64):
        super().__init__()
        self.mlp = nn.Sequential(nn.LayerNorm(dim), nn.Linear(dim, hidden), nn.GELU(),
                                 nn.Linear(hidden, TASK_OUTPUTS["nav"]))

    def forward(self, cls: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.mlp(cls))

    def encode(self, action: torch.Tensor) -> torch.Tensor:
        """The loss space of the nav action is the action itself ([-1, 1] already)."""
        return action

    def predict_loss_space(self, cls: torch.Tensor) -> torch.Tensor:
        return self(cls)


class ArmHead(nn.Module):
    """PolicyHeadArm: class token [B, D] -> pose [x, y, z, roll, pitch, yaw] [B, 6].

    Deeper than the nav head (two hidden layers) and unbounded. Two spaces besides the pose:

    - the MLP's 7 outputs u: x, y, z, roll and pitch standardised, pose = mean + scale * u,
      so the network works at unit scale whatever the spread of each coordinate; and the
      yaw as (cos 4 yaw, sin 4 yaw). A cube looks the same a quarter turn on, so its yaw
      label is folded into [-45, 45) degrees and jumps from one end to the other where the
      cube's faces pass 45 degrees: a regressed angle learns the mean there, the 4-fold
      unit vector is continuous.
    - the loss space (`encode`), where training compares prediction and target: x, y, z in
      centimetres and roll, pitch in units of 0.05 rad (LOSS_UNIT) from the mean, the yaw
      pair as above. A grasp needs about a centimetre; in standard deviations a centimetre
      along the belt (targets spread 20 cm) is 0.05, deep in Smooth L1's quadratic zone
      where its gradient fades, so a model trained there settles 2-4 cm off and spends its
      loss on the yaw (docs/policy.md). In raw metres it would be 0.01, worse still.

    `mean` and `scale` [6] are buffers set from the training targets (`set_target_stats`;
    the yaw's entries are unused): they travel in the state_dict, so the model always
    outputs metres and radians, yaw in (-pi/4, pi/4].
    """

    YAW_FOLD = 4            # the cube's rotational symmetry about the vertical
    LOSS_DIMS = 7           # 5 linear + (cos, sin) of the folded yaw
    LOSS_UNIT = (0.01, 0.01, 0.01, 0.05, 0.05)   # m, m, m, rad, rad per unit of loss space

    def __init__(self, dim: int = 64, hidden: int = 128):
        super().__init__()
        self.mlp = nn.Sequential(nn.LayerNorm(dim), nn.Linear(dim, hidden), nn.GELU(),
                                 nn.Linear(hidden, hidden // 2), nn.GELU(),
                                 nn.Linear(hidden // 2, self.LOSS_DIMS))
        self.register_buffer("mean", torch.zeros(TASK_OUTPUTS["arm"]))
        self.register_buffer("scale", torch.ones(TASK_OUTPUTS["arm"]))
        self.register_buffer("loss_unit", torch.tensor(self.LOSS_UNIT), persistent=False)

    def set_target_stats(self, mean, scale) -> None:
        """Pose standardisation from the training targets: mean [6], scale [6] (> 0)."""
        self.mean.copy_(torch.as_tensor(mean, dtype=self.mean.dtype))
        self.scale.copy_(torch.as_tensor(scale, dtype=self.scale.dtype))

    def encode(self, pose: torch.Tensor) -> torch.Tensor:
        """[B, 6] pose in metres/radians -> [B, 7] loss space (where the loss is taken)."""
        lin = (pose[:, :5] - self.mean[:5]) / self.loss_unit
        k = self.YAW_FOLD * pose[:, 5:6]
        return torch.cat([lin, torch.cos(k), torch.sin(k)], dim=1)

    def decode(self, u: torch.Tensor) -> torch.Tensor:
        """[B, 7] MLP output -> [B, 6] pose; the (cos, sin) pair need not be unit length."""
        lin = self.mean[:5] + self.scale[:5] * u[:, :5]
        yaw = torch.atan2(u[:, 6:7], u[:, 5:6]) / self.YAW_FOLD
        return torch.cat([lin, yaw], dim=1)

    def forward(self, cls: torch.Tensor) -> torch.Tensor:
        return self.decode(self.mlp(cls))

    def predict_loss_space(self, cls: torch.Tensor) -> torch.Tensor:
        """Class token [B, D] -> the prediction in the loss space [B, 7], straight from the
        MLP: encode(forward(cls)) would normalise the yaw pair, whose gradient shrinks as
        1/|pair| and turns only the pair's direction; compared as the MLP gives it, the pair
        is a plain regression target."""
        u = self.mlp(cls)
        return torch.cat([u[:, :5] * self.scale[:5] / self.loss_unit, u[:, 5:]], dim=1)


class RecurrentState(nn.Module):
    """A GRU cell over the per-tick class tokens, added back to the token:
    (token [B, D], state [B, D]) -> (features [B, D], new state [B, D]).

        state' = GRUCell(token, state)
        features = token + state'

    The residual keeps the tick's own evidence one addition away from the head, so the
    cell only has to learn what the tick does not show (where the target was when the
    event camera, holding it still, stops seeing it). Issue 65, item 2.
    """

    def __init__(self, dim: int = 64):
        super().__init__()
        self.cell = nn.GRUCell(dim, dim)

    def forward(self, token: torch.Tensor, state: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        state = self.cell(token, state)
        return token + state, state


class TargetHead(nn.Module):
    """The auxiliary head: features [B, D] -> [B, 3], the target's image position as a
    fraction of the width and height (sigmoid, 0..1) and its visibility as a logit.

    Trained from the sim's privileged truth (truth/centroid, truth/visible), during
    training only: it grounds the encoder in where the target is, and the actor never
    reads it. Issue 65, item 2.
    """

    OUTPUTS = 3

    def __init__(self, dim: int = 64, hidden: int = 64):
        super().__init__()
        self.mlp = nn.Sequential(nn.LayerNorm(dim), nn.Linear(dim, hidden), nn.GELU(),
                                 nn.Linear(hidden, self.OUTPUTS))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        u = self.mlp(features)
        return torch.cat([torch.sigmoid(u[..., :2]), u[..., 2:]], dim=-1)


class ERP(nn.Module):
    """Event-based robot policy: [B, in_channels, size, size] float -> [B, 2] (nav) or [B, 6] (arm).

    Args:
        task: "nav" or "arm" (selects the head).
        in_channels: 3 (rgb), 2 (event) or 5 (rgb+event); rgb channels come first.
        size: input side in pixels, a multiple of ``patch`` (160 -> 100 tokens, 640 -> 1600).
        dim, heads, mlp, dropout, patch: the paper's 64, 4, 256, 0.1, 16.
        stem: "patch" (the paper's linear patch embedding), "conv" (ConvStem), or for
            rgb+event inputs only "dual" (DualStem) or "gated" (GatedFusionStem).
        memory: "none" (the paper's: each tick on its own) or "gru" (RecurrentState: a
            state [B, dim] carried across ticks; `step` and `sequence` take and return it).
        aux: add the TargetHead (`sequence` returns its output; training only).
    """

    def __init__(self, task: str, in_channels: int, size: int = 160, *, dim: int = 64,
                 heads: int = 4, mlp: int = 256, dropout: float = 0.1, patch: int = 16,
                 stem: str = "patch", memory: str = "none", aux: bool = False):
        super().__init__()
        if task not in TASK_OUTPUTS:
            raise ValueError(f"unknown task {task!r} (nav, arm)")
        if stem not in STEMS:
            raise ValueError(f"unknown stem {stem!r} ({', '.join(STEMS)})")
        if size % patch:
            raise ValueError(f"size {size} is not a multiple of the patch size {patch}")
        if memory not in MEMORIES:
            raise ValueError(f"unknown memory {memory!r} ({', '.join(MEMORIES)})")
        self.task, self.in_channels, self.size, self.stem = task, in_channels, size, stem
        self.memory, self.aux, self.dim = memory, bool(aux), dim
        self.embed = STEMS[stem](in_channels, dim, patch)
        self.tokens = TokenSequence(size // patch, dim)
        # Pre-norm, as in ViT and RVT, whose formulation section 3.4 says it follows (its
        # "layer normalization ... after each sub-layer" could also read as post-norm).
        # Measured on a "find the square" set at 160 px with the paper's settings: pre-norm
        # reaches val MSE 0.0024 in 10 epochs, post-norm stays at the mean (0.227) for all
        # 10 (docs/policy.md). The head's LayerNorm is ViT's final norm.
        # nn.TransformerEncoderLayer also gives the fused CPU inference fast path in eval().
        self.encoder = nn.TransformerEncoderLayer(dim, heads, dim_feedforward=mlp,
                                                  dropout=dropout, activation="gelu",
                                                  batch_first=True, norm_first=True)
        self.head = NavHead(dim) if task == "nav" else ArmHead(dim)
        # created after the head, so that a memoryless model draws its weights as before
        self.recurrent = RecurrentState(dim) if memory == "gru" else None
        self.target_head = TargetHead(dim) if aux else None

    @property
    def state_size(self) -> int:
        """The width of the state `step` carries: dim with memory, 0 without."""
        return self.dim if self.recurrent is not None else 0

    def initial_state(self, batch: int = 1) -> torch.Tensor:
        """The state at an episode's first tick: zeros [batch, state_size]."""
        return torch.zeros(batch, self.state_size)

    def _class_token(self, x: torch.Tensor) -> torch.Tensor:
        """x [B, C, S, S] -> the encoded class token [B, dim]."""
        if x.shape[1:] != (self.in_channels, self.size, self.size):
            raise ValueError(f"expected input [B, {self.in_channels}, {self.size}, {self.size}], "
                             f"got {list(x.shape)}")
        return self.encoder(self.tokens(self.embed(x)))[:, 0]

    def _first_tick(self, x: torch.Tensor) -> torch.Tensor:
        """x [B, C, S, S] -> the feature the head reads [B, dim] at a tick with nothing
        remembered: the class token, through the recurrent cell from the initial state
        where there is one."""
        token = self._class_token(x)
        if self.recurrent is not None:
            token, _ = self.recurrent(token, token.new_zeros(token.shape))
        return token

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x [B, C, S, S] -> action [B, 2] or pose [B, 6]; with memory, from the initial
        state (a tick with nothing remembered)."""
        return self.head(self._first_tick(x))

    def step(self, x: torch.Tensor, state: torch.Tensor
             ) -> tuple[torch.Tensor, torch.Tensor]:
        """One control tick: (x [B, C, S, S], state [B, state_size]) -> (action [B, 2] or
        pose [B, 6], the next state [B, state_size]). Without memory the state is
        returned as given (empty)."""
        token = self._class_token(x)
        if self.recurrent is not None:
            token, state = self.recurrent(token, state)
        return self.head(token), state

    def sequence(self, x: torch.Tensor, state: torch.Tensor, valid: torch.Tensor | None = None
                 ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """L ticks of B sequences, for training: (x [B, L, C, S, S], state [B, state_size],
        valid [B, L] bool or None: False at padding, whose ticks leave the state as it
        was) -> (prediction in the loss space [B, L, 2 | 7], TargetHead output [B, L, 3] or
        None, the state after the last tick [B, state_size]).

        The L frames of every sequence go through the encoder as one batch of B * L; only
        the GRU runs tick by tick."""
        b, n = x.shape[:2]
        tokens = self._class_token(x.reshape(b * n, *x.shape[2:])).reshape(b, n, -1)
        if self.recurrent is not None:
            feats = []
            for t in range(n):
                f, stepped = self.recurrent(tokens[:, t], state)
                state = stepped if valid is None else \
                    torch.where(valid[:, t, None], stepped, state)
                feats.append(f)
            tokens = torch.stack(feats, dim=1)
        flat = tokens.reshape(b * n, -1)
        pred = self.head.predict_loss_space(flat).reshape(b, n, -1)
        aux = (self.target_head(flat).reshape(b, n, -1)
               if self.target_head is not None else None)
        return pred, aux, state

    def predict_loss_space(self, x: torch.Tensor) -> torch.Tensor:
        """x [B, C, S, S] -> the prediction where training compares it with loss_space(y):
        the arm head's [B, 7] (ArmHead.predict_loss_space), the nav action as it is; with
        memory, from the initial state, as `forward` (one tick of `sequence`)."""
        return self.head.predict_loss_space(self._first_tick(x))

    def loss_space(self, y: torch.Tensor) -> torch.Tensor:
        """Targets [B, 6 | 2] in the space the training loss is taken: the arm head's
        encoding [B, 7], the nav action as it is ([-1, 1] already)."""
        return self.head.encode(y)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
