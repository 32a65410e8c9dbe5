"""Seed ensembles: K independently trained surrogates merged into ONE wider network.

A free-running ensemble averages its members' angular velocities every step and integrates
the mean, so all members see the same fed-back angle::

    omega_hat[k+1] = (1/K) sum_m omega_m(theta_hat[0..k], u[0..k]);
    theta_hat[k+1] = clip(theta_hat[k] + T_s * omega_hat[k+1])

Members with the same cell and depth are exactly one recurrent network whose hidden state is
the members' states side by side: every weight matrix is block-diagonal (per gate), the
input layer stacks the members' rows, and the output layer averages the members' heads.
:func:`merge` builds that network, so a merged checkpoint runs everywhere a single one does
(``ClosedLoop``, the vector env, the fused engine, ONNX export) with no ensemble code path to
keep equal.  Members may differ in normalisation (each member's input and output affine maps
are folded into its block), in width and in the training data: they must share the machine
(joints, rate, periodic flags, kinds, command ranges, inputs: ``MachineSpec.mismatch``),
cell, depth, window, rollout mode, end stops, play features and velocity feature.  The end
stops and speed bounds each member took from its data may differ; the merged model keeps
the widest (:func:`merged_spec`).

:func:`~.reference.rollout_reference` with a list of members is the plain loop (members
stepped one by one, omega averaged in NumPy) that the merged network is tested against.

:class:`MemberHead` gives every member's own omega back from a merged network (the spread
of the members is the ensemble's uncertainty, :mod:`.uncertainty`): the network runs as
always, a hook records the head's hidden layer, and the last layer is applied per member
block (``merge`` stores each member's output bias in ``metrics["ensemble"]["member_bias"]``).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace
from typing import Any

import numpy as np
import torch

from ..errors import ConfigError
from ..spec import SOURCE_META, MachineSpec
from .model import CELL_GATES, ModelConfig, Surrogate, SurrogateNet
from .prior import PRIOR_MAP


def check_members(
    surs: Sequence[Surrogate], *, same_gains: bool = True, labels: Sequence[str] | None = None
) -> None:
    """Raise :class:`ConfigError` naming the first member that cannot join the first one
    (``same_gains=False``: speed priors may differ in their gains, as in a composite;
    ``labels``: what to call each member, e.g. its file, instead of its index)."""

    def who(i: int) -> str:
        return labels[i] if labels is not None else f"ensemble member {i} ({surs[i].name})"

    if len(surs) < 1:
        raise ConfigError("an ensemble needs at least one member")
    ref = surs[0]
    if ref.model_cfg.cell not in CELL_GATES:
        raise ConfigError(f"only LSTM/GRU surrogates can be ensembled, not '{ref.model_cfg.cell}'")
    for i, s in enumerate(surs):
        bad = non_finite_weight(s)
        if bad is not None:
            raise ConfigError(
                f"{who(i)} has non-finite weights ({bad}): its training "
                "diverged; re-train it (lower train.lr) or leave it out"
            )
    for i, s in enumerate(surs[1:], start=1):
        # the machine, not the envelope its training data gave it (merged_spec widens that)
        diff = ref.spec.mismatch(s.spec)
        checks = [
            (diff is None, f"machine ({diff})"),
            (s.model_cfg.cell == ref.model_cfg.cell, "cell"),
            (s.model_cfg.n_layer == ref.model_cfg.n_layer, "number of layers"),
            (s.model_cfg.window == ref.model_cfg.window, "window W"),
            (s.mode == ref.mode, "rollout mode"),
            (bool(s.end_stops) == bool(ref.end_stops), "end stops"),
            (torch.equal(s.norm.play.cpu(), ref.norm.play.cpu()), "play widths"),
            (s.norm.omega_in == ref.norm.omega_in, "velocity feature"),
            (s.norm.lags == ref.norm.lags, "command delays (a static map's delay)"),
            (s.model_cfg.residual == ref.model_cfg.residual, "residual head"),
            (
                _same_prior(s, ref, same_gains=same_gains),
                "speed prior (another map, or other joints on the static map)",
            ),
            (s.model_cfg.n_feature == ref.model_cfg.n_feature, "input features"),
        ]
        for ok, what in checks:
            if not ok:
                raise ConfigError(
                    f"{who(i)} differs from {who(0)} in its {what}; "
                    "merge surrogates trained on the same machine with the same architecture"
                )
    for i, s in enumerate(surs):
        for k, t in enumerate(surs[:i]):
            if _same_weights(s, t):
                raise ConfigError(
                    f"{who(i)} has the same weights as {who(k)}: the "
                    "same model twice is no ensemble; give each member once"
                )


def merged_spec(specs: Sequence[MachineSpec]) -> MachineSpec:
    """The machine of merged members (one machine: :meth:`MachineSpec.mismatch`): the first
    member's, with each joint's envelope the widest of the members' (the lowest
    ``theta_min``, the highest ``theta_max`` and ``omega_max``; None, no bound, where a member
    has none) and the data sources of all (:data:`~excavator_surrogate.spec.SOURCE_META`).
    Members trained on other data of the machine derive other bounds from it
    (:func:`~.envelope.fill_envelope`); the merged model's are those of all their data."""

    def widest(values: list[float | None], pick: Any) -> float | None:
        return None if any(v is None for v in values) else float(pick(values))

    joints = [
        replace(
            js[0],
            theta_min=widest([j.theta_min for j in js], min),
            theta_max=widest([j.theta_max for j in js], max),
            omega_max=widest([j.omega_max for j in js], max),
        )
        for js in zip(*(s.joints for s in specs))
    ]
    meta = dict(specs[0].meta)
    sources = {p for s in specs for p in str(s.meta.get(SOURCE_META) or "").split("+") if p}
    if sources:
        meta[SOURCE_META] = "+".join(sorted(sources))
    return replace(specs[0], joints=tuple(joints), meta=meta)


def _same_prior(a: Surrogate, b: Surrogate, *, same_gains: bool = True) -> bool:
    """Both without a speed prior, or both with the same map (the same training data); with
    ``same_gains=False`` only the columns it reads must agree (see :func:`merge`)."""
    pa, pb = getattr(a.net, "prior", None), getattr(b.net, "prior", None)
    if pa is None or pb is None:
        return pa is None and pb is None
    names = PRIOR_MAP if same_gains else ("cols",)
    return all(torch.equal(getattr(pa, n).cpu(), getattr(pb, n).cpu()) for n in names)


def non_finite_weight(sur: Surrogate) -> str | None:
    """Name of the first NaN/inf parameter of ``sur``'s network (None: all finite)."""
    for name, p in sur.net.named_parameters():
        if not bool(torch.isfinite(p).all()):
            return name
    return None


def _same_weights(a: Surrogate, b: Surrogate) -> bool:
    """Same network weights and normalisation: the same model (e.g. one file given twice)."""

    def same(sa: dict[str, Any], sb: dict[str, Any]) -> bool:
        return sa.keys() == sb.keys() and all(
            not isinstance(sa[k], torch.Tensor)
            or (sa[k].shape == sb[k].shape and torch.equal(sa[k].cpu(), sb[k].cpu()))
            for k in sa
        )

    return same(a.net.state_dict(), b.net.state_dict()) and same(
        a.norm.state_dict(), b.norm.state_dict()
    )


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().double().cpu().numpy()


def merge(
    surs: Sequence[Surrogate],
    *,
    name: str | None = None,
    joint_weights: Sequence[Sequence[float]] | None = None,
    labels: Sequence[str] | None = None,
) -> Surrogate:
    """Merge K surrogates into one whose omega is the mean of theirs (see the module docstring).

    Args:
        surs: K >= 1 members (LSTM or GRU, same spec/cell/depth/window/mode/end stops/play/velocity feature/head).
        name: label of the merged model (default ``"<cell>-ensemble-K"``).
        joint_weights: (K, n_joint) member ``m``'s weight on joint ``j``, each column summing
            to 1, or None (``1/K`` everywhere: the ensemble).  A weighted merge is a
            **composite**, one network whose joint ``j`` is ``sum_m W[m, j] omega_m,j``
            (e.g. each joint from one member), not an ensemble: its metrics say
            ``composite``, and it joins ensembles as one member.  Speed priors then only
            have to read the same columns: the merged map's gain on joint ``j`` is
            ``sum_m W[m, j] k_m,j`` (exact: the map is linear in its gains), its dead zone
            that of the members that drive joint ``j`` with a non-zero gain (they must agree).
        labels: what the errors call each member (e.g. its file); default its index.

    Returns:
        A :class:`Surrogate` with hidden width ``sum_m hidden_m`` and head width
        ``sum_m head_hidden_m``, on the CPU in float32, in eval mode, with member 0's
        normalisation; ``metrics["ensemble"]`` lists the members.

    Raises:
        ConfigError: members that cannot be merged (one line naming the member and what differs).
    """
    check_members(surs, same_gains=joint_weights is None, labels=labels)
    ref = surs[0]
    n_member = len(surs)
    n_joint = ref.spec.n_joint
    if joint_weights is None:
        weights = np.full((n_member, n_joint), 1.0 / n_member)
    else:
        weights = np.asarray(joint_weights, dtype=np.float64)
        if (
            weights.shape != (n_member, n_joint)
            or not np.all(weights >= 0)
            or not np.allclose(weights.sum(0), 1.0)
        ):
            raise ConfigError(
                f"merge: joint_weights must be ({n_member}, {n_joint}) non-negative weights "
                f"whose columns sum to 1, got {weights.tolist()}"
            )
    cell = ref.model_cfg.cell
    n_gate = CELL_GATES[cell]
    n_layer = ref.model_cfg.n_layer
    hid = [s.model_cfg.hidden for s in surs]
    head = [s.model_cfg.head_hidden for s in surs]
    h_off = np.concatenate([[0], np.cumsum(hid)])
    f_off = np.concatenate([[0], np.cumsum(head)])
    h_tot, f_tot = int(h_off[-1]), int(f_off[-1])
    residual = ref.model_cfg.residual
    prior = ref.model_cfg.prior
    no_ym = residual or prior  # omega = mean_m ys_m head_m + (w or s(u)): no y_mean terms
    norm0 = ref.norm.to("cpu", torch.float32)
    xm0, xs0 = _np(norm0.x_mean), _np(norm0.x_std)
    ym0, ys0 = _np(norm0.y_mean), _np(norm0.y_std)
    n_in = [ref.model_cfg.n_feature] + [h_tot] * (n_layer - 1)
    w_ih = [np.zeros((n_gate * h_tot, n_in[k])) for k in range(n_layer)]
    w_hh = [np.zeros((n_gate * h_tot, h_tot)) for _ in range(n_layer)]
    b_ih = [np.zeros(n_gate * h_tot) for _ in range(n_layer)]
    b_hh = [np.zeros(n_gate * h_tot) for _ in range(n_layer)]
    w1 = np.zeros((f_tot, h_tot))
    b1 = np.zeros(f_tot)
    w2 = np.zeros((n_joint, f_tot))
    b2 = np.zeros(n_joint)
    member_bias = []  # member m's share of b2, times n_member (MemberHead splits the head back)
    for m, s in enumerate(surs):
        rnn, lin1, lin2 = s.net.rnn, s.net.head[0], s.net.head[2]
        norm = s.norm.to("cpu", torch.float32)
        xm, xs = _np(norm.x_mean), _np(norm.x_std)
        ym, ys = _np(norm.y_mean), _np(norm.y_std)
        hm, lo, hi = hid[m], int(h_off[m]), int(h_off[m + 1])
        for k in range(n_layer):
            wi, wh = _np(getattr(rnn, f"weight_ih_l{k}")), _np(getattr(rnn, f"weight_hh_l{k}"))
            bi, bh = _np(getattr(rnn, f"bias_ih_l{k}")), _np(getattr(rnn, f"bias_hh_l{k}"))
            if k == 0:
                # member input x_m = x * (xs0 / xs_m) + (xm0 - xm_m) / xs_m for the shared x
                bi = bi + wi @ ((xm0 - xm) / xs)
                wi = wi * (xs0 / xs)[None, :]
            for g in range(n_gate):
                rows = slice(g * h_tot + lo, g * h_tot + hi)
                src = slice(g * hm, (g + 1) * hm)
                # W_ih: layer 0 reads every shared feature, deeper layers only member m's block
                if k == 0:
                    w_ih[k][rows] = wi[src]
                else:
                    w_ih[k][rows, lo:hi] = wi[src]
                # W_hh: block-diagonal, member m's state feeds only member m's gates
                w_hh[k][rows, lo:hi] = wh[src]
                b_ih[k][rows] = bi[src]
                b_hh[k][rows] = bh[src]
        f_lo, f_hi = int(f_off[m]), int(f_off[m + 1])
        # a_m = relu(W1_m h_m + b1_m): block-diagonal first head layer
        w1[f_lo:f_hi, lo:hi] = _np(lin1.weight)
        b1[f_lo:f_hi] = _np(lin1.bias)
        # y = (sum_m w_m (ys_m (W2_m a_m + b2_m) + ym_m) - ym0) / ys0   (w_m = 1/K: the mean;
        # member 0's output scale)
        # residual: omega = sum_m w_m ys_m (W2_m a_m + b2_m) + w = ys0 y + w, so no ym terms;
        # prior: the same with s(u) for w (the merged map is the members' weighted map)
        wm = weights[m]
        w2[:, f_lo:f_hi] = _np(lin2.weight) * (ys * wm / ys0)[:, None]
        b2 += wm * (ys * _np(lin2.bias) + (0.0 if no_ym else ym)) / ys0
        member_bias.append((ys * _np(lin2.bias) + (0.0 if no_ym else ym - ym0)) / ys0)
    if not no_ym:
        b2 -= ym0 / ys0

    mcfg = ModelConfig(
        n_feature=ref.model_cfg.n_feature,
        n_joint=n_joint,
        window=ref.model_cfg.window,
        hidden=h_tot,
        n_layer=n_layer,
        cell=cell,
        head_hidden=f_tot,
        residual=residual,
        prior=prior,
    )
    net = SurrogateNet(mcfg)
    if net.prior is not None:  # the members' map, reading the shared features of norm0
        if joint_weights is None:  # one map: member 0's
            p0 = ref.net.prior
            fit = {k: getattr(p0, k).cpu().tolist() for k in PRIOR_MAP}
        else:
            fit = _merged_map(surs, weights)
        net.prior.load_fit(**fit, norm=norm0)
    f32 = torch.float32
    with torch.no_grad():
        for k in range(n_layer):
            for attr, a in (
                (f"weight_ih_l{k}", w_ih[k]),
                (f"weight_hh_l{k}", w_hh[k]),
                (f"bias_ih_l{k}", b_ih[k]),
                (f"bias_hh_l{k}", b_hh[k]),
            ):
                getattr(net.rnn, attr).copy_(torch.tensor(a, dtype=f32))
        net.head[0].weight.copy_(torch.tensor(w1, dtype=f32))
        net.head[0].bias.copy_(torch.tensor(b1, dtype=f32))
        net.head[2].weight.copy_(torch.tensor(w2, dtype=f32))
        net.head[2].bias.copy_(torch.tensor(b2, dtype=f32))
    net.eval()
    info: dict[str, Any] = {
        "n_member": n_member,
        "hidden": hid,
        "head_hidden": head,
        "member_bias": [[float(v) for v in b] for b in member_bias],
        "members": [
            {
                "name": s.name,
                "seed": (s.train_config or {}).get("seed"),
                "val_error": (s.metrics or {}).get("val_error"),
                "epoch": (s.metrics or {}).get("epoch"),
            }
            for s in surs
        ],
    }
    if joint_weights is not None:  # one network: its parts are not an ensemble's members
        del info["member_bias"]
        info = {**info, "joint_weights": weights.tolist()}
    return Surrogate(
        net=net,
        spec=merged_spec([s.spec for s in surs]),
        norm=norm0,
        model_cfg=mcfg,
        mode=ref.mode,
        train_config=dict(ref.train_config or {}),
        metrics={"ensemble" if joint_weights is None else "composite": info},
        name=name
        or (
            f"{cell}-composite-{n_member}"
            if joint_weights is not None
            else f"{cell}-ensemble-{n_member}"
            if n_member > 1
            else ref.name
        ),
        end_stops=ref.end_stops,
    )


def _merged_map(surs: Sequence[Surrogate], weights: np.ndarray) -> dict[str, list[float]]:
    """The merged speed prior of ``surs`` (all with one) under ``weights`` (K, n_joint):
    gains ``sum_m W[m, j] k_m,j``, dead zones of the members driving joint ``j`` with a
    non-zero gain (all equal: one map, other gains), columns of member 0."""
    priors = [s.net.prior for s in surs]
    get = {n: np.array([_np(getattr(p, n)) for p in priors]) for n in PRIOR_MAP}
    out: dict[str, list[float]] = {"cols": get["cols"][0].astype(int).tolist()}
    for n in ("k_pos", "k_neg"):
        out[n] = (weights * get[n]).sum(0).tolist()
    live = (weights > 0) & ((get["k_pos"] != 0) | (get["k_neg"] != 0))  # (K, n_joint)
    for n in ("a_pos", "a_neg"):
        col = []
        for j in range(weights.shape[1]):
            vals = get[n][live[:, j], j]
            if len(vals) and not np.all(vals == vals[0]):
                raise ConfigError(
                    f"merge: the members' maps differ in their dead zone on joint {j} "
                    f"({n} {vals.tolist()}): merge members of one training data set"
                )
            col.append(float(vals[0]) if len(vals) else 0.0)
        out[n] = col
    return out


def n_member(sur: Surrogate) -> int:
    """Number of members a surrogate was merged from (1 for a single network)."""
    ens = (sur.metrics or {}).get("ensemble")
    return int(ens["n_member"]) if isinstance(ens, dict) and "n_member" in ens else 1


class MemberHead:
    """The merged output layer split back into its members' (see :func:`member_head`).

    The merged head is ``y = W2 a + b2`` with ``a = relu(W1 h + b1)``, ``a`` the members'
    head activations side by side; member ``m``'s own normalised output (in member 0's
    output normalisation) is ``y_m = M W2[:, block_m] a[block_m] + beta_m``, and
    ``mean_m y_m = y`` exactly (up to rounding).
    """

    def __init__(self, sur: Surrogate) -> None:
        info = sur.metrics["ensemble"]
        self.n_member = m = int(info["n_member"])
        self.residual = bool(sur.model_cfg.residual)
        self.n_joint = sur.spec.n_joint
        net = sur.net
        self.prior = getattr(net, "prior", None)
        self._act = net.head[1]
        w2 = net.head[2].weight.detach()  # (n_joint, f_tot)
        off = np.concatenate([[0], np.cumsum(info["head_hidden"])]).astype(int)
        mask = torch.zeros(m, 1, w2.shape[1], dtype=w2.dtype, device=w2.device)
        for i in range(m):
            mask[i, :, off[i] : off[i + 1]] = 1.0
        self.w2 = (m * w2.unsqueeze(0) * mask).contiguous()  # (M, n_joint, f_tot)
        self.bias = torch.tensor(info["member_bias"], dtype=w2.dtype, device=w2.device)
        dev = info.get("map_gain_dev") if self.prior is not None else None
        self.map_dev = None if dev is None else torch.tensor(dev, dtype=w2.dtype, device=w2.device)
        """(M, n_joint) member ``m`` drives a static-map joint with gain ``1 + map_dev[m]``
        (:func:`.series.with_map_joints`), or None."""
        self.a: torch.Tensor | None = None
        """The head activations ``(..., f_tot)`` of the last captured network call."""

    def folded(
        self, norm: Any, *, additive: bool
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """The members' output layer in physical units, float32, for runtimes that take the
        head activations ``a`` (n_batch, f_tot) themselves::

            omega_m = a @ w2m[m] + b2m[m] (+ (1 + map_dev[m]) base)

        Args:
            norm: the surrogate's normalisation (``y_std``, ``y_mean``).
            additive: the head's output is added to a base (residual head or speed prior), so
                it carries no ``y_mean``.

        Returns:
            ``w2m`` (M, f_tot, n_joint), ``b2m`` (M, 1, n_joint) and ``map_dev`` (M, 1,
            n_joint) or None (no static-map joint).
        """
        y_std, y_mean = norm.y_std.float(), norm.y_mean.float()
        w2m = (self.w2 * y_std[None, :, None]).transpose(1, 2).contiguous()
        b2m = (self.bias * y_std + (0.0 if additive else y_mean))[:, None, :]
        map_dev = None if self.map_dev is None else self.map_dev.float()[:, None, :]
        return w2m, b2m, map_dev

    @contextmanager
    def capture(self) -> Iterator[MemberHead]:
        """Record the head's hidden activations of the network calls inside the block."""

        def hook(_mod: Any, _inp: Any, out: torch.Tensor) -> None:
            self.a = out

        handle = self._act.register_forward_hook(hook)
        try:
            yield self
        finally:
            handle.remove()

    def outputs(self, x: torch.Tensor) -> torch.Tensor:
        """Every member's normalised output for the captured call on inputs ``x``.

        Args:
            x: (n_batch, n_feature) normalised features of the sample the call predicted from
                (the velocity feature of a residual head, or the commands of a speed prior,
                are read from it).

        Returns:
            (M, n_batch, n_joint) normalised omega per member (member 0's normalisation).
        """
        if self.a is None:
            raise RuntimeError("MemberHead.outputs() needs a network call inside capture()")
        y = torch.einsum("nf,mjf->mnj", self.a, self.w2) + self.bias[:, None, :]
        if self.residual:
            y = y + x[..., -self.n_joint :]
        if self.prior is not None:
            y = y + self.prior(x)
            if self.map_dev is not None:  # + dev_m s(u), in the output normalisation
                y = y + self.map_dev[:, None, :] * (self.prior.raw(x) / self.prior.y_std)
        return y


def member_head(sur: Surrogate) -> MemberHead | None:
    """The :class:`MemberHead` of a merged ensemble, or ``None``: a single network, or a
    checkpoint merged before ``merge`` recorded the members' output biases (re-merge it)."""
    info = (sur.metrics or {}).get("ensemble")
    if n_member(sur) < 2 or not isinstance(info, dict) or "member_bias" not in info:
        return None
    if not hasattr(sur.net, "head"):
        return None
    return MemberHead(sur)
