"""The control-law protocol and the law registry: one class per law, found by its scenario name.

A law is a :class:`Law` subclass registered with :func:`register_law`. Everything else (the
scenario schema's ``[loops.<name>.controller]`` keys, ``ftstab list``, RunInfo/LoopInfo
``law_params``, the run loop, the logs) reads it from the registry. To add a law:

1. write a module ``ftstab_mj/control/laws/<name>.py`` (every module of that package is imported);
2. in it, subclass :class:`Law`: ``name``, ``summary``, ``params`` (:class:`Param`), ``lyapunov``;
3. implement ``from_params(r, values)``, ``evaluate(z, state)`` and, if it has a state,
   ``state_size``, ``initial_state`` and ``state_derivative`` (``advance`` if Euler is not exact);
4. decorate it with ``@register_law``; give it a ``native_code`` (and ``native_params``) only when the C
   kernel (ftstab_mj/simulation/native/laws.c) has its twin, pinned against this NumPy code by the tests.

The protocol (shapes: z (..., r) chain state, state (..., m) with m = ``law.state_size``):

* ``evaluate(z, state) -> LawOutput``: the control u and the logged quantities. V1 and dV1_dzr are a
  Lyapunov function of the closed loop and its derivative in z_r (used by the worst-case
  disturbance and the metrics) when ``lyapunov`` is True, NaN otherwise; u0 is the nominal part of u
  (NaN when the law has none); gamma_hat and phi_hat are the gain and disturbance estimates the law
  uses in u = gamma_hat u0 + phi_hat sign(u0) (NaN when u is not of that form).
* ``state_derivative(z, state, out)``: the law's own state equation x' = f(z, x) (continuous time).
* ``advance(z, state, out, h)``: the state one control period h later with z held over the period
  (zero-order hold, what a sampled controller does). Default: x + h f, exact when f does not depend
  on x; a law whose f does (the adaptive phi_hat) integrates it itself.
* ``for_period(h)``: the law as run with control period h (default: itself); the run loop calls it once.
* The run loop keeps the state in MuJoCo's userdata (``state_size`` slots per loop), so a saved
  simulation state (mjSTATE_INTEGRATION) holds it and save/restore is exact.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, ClassVar, NamedTuple

import numpy as np

from ftstab_mj.config.errors import ParameterError
from ftstab_mj.config.validate import non_negative, one_of, open_unit_interval, positive  # noqa: F401 - the checks Params use

REQUIRED = object()  # Param.default of a parameter the scenario must give
COMPUTED = "computed"  # the value of a Param with plant_bound that stands for the plant's bound (scenario loader)


class LawOutput(NamedTuple):
    """One evaluation of a law; every field has the batch shape (...). Units: chain units."""

    u: np.ndarray  # control applied to the plant
    u0: np.ndarray  # nominal part of u (Hong's u0), NaN if none
    V1: np.ndarray  # Lyapunov function, NaN if the law has none
    dV1_dzr: np.ndarray  # dV1/dz_r, NaN if no Lyapunov function
    gamma_hat: np.ndarray  # gain estimate in u = gamma_hat u0 + phi_hat sign(u0), NaN if not of that form
    phi_hat: np.ndarray  # disturbance estimate in the same form, NaN if not of that form


@dataclass(frozen=True)
class Param:
    """One scenario parameter of a law (a key of ``[loops.<name>.controller]``).

    type: the TOML value's Python type (float, str, tuple[float, ...], float | str);
    doc: what it is; units: its units, "dimensionless" for a pure number (an exponent, a ratio), ""
    only for a str parameter (a word from a list; tests/test_law_params.py); check: value -> None when allowed,
    else the text of what is allowed (the loader quotes it); default: REQUIRED or a value;
    plant_bound: "phibar" or "gamma_m" when the word "computed" stands for the plant's bound.
    Two laws may share a parameter only with the same declaration (one key, one meaning).
    """

    name: str
    type: Any
    doc: str
    units: str = ""
    check: Callable[[Any], str | None] | None = None
    default: Any = REQUIRED
    plant_bound: str | None = None

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    def describe(self) -> str:
        """"doc (units)", as the schema and ``ftstab list`` show it."""
        return f"{self.doc} ({self.units})" if self.units else self.doc


class Law:
    """Base of the registered laws: class attributes say what the law is, methods what it does."""

    name: ClassVar[str] = ""  # the scenario's `law` value
    summary: ClassVar[str] = ""  # one line for `ftstab list`, with the source (paper, section)
    base_params: ClassVar[tuple[Param, ...]] = ()  # of the controller it is built on (LoopInfo.hong)
    params: ClassVar[tuple[Param, ...]] = ()  # its own (LoopInfo.law_params)
    lyapunov: ClassVar[bool] = False  # V1, dV1_dzr are a Lyapunov function and its gradient
    # The law's number in the C kernel (laws.h), declared by the class itself (a subclass that overrides the
    # maths does not inherit the twin), with :meth:`native_params`; None: no twin, the run loop's Python path.
    native_code: ClassVar[int | None] = None
    # What the law guarantees: metrics, report, viewers, stages and expectations read these, never its name.
    # time_bound: Theorem 1's envelope and T(z0) = V1(z0)^(1 - alpha) / (c (1 - alpha)) hold, from the
    # certificate of ``hong`` (c, alpha), whenever :meth:`bound_holds` says so for the plant's true bounds.
    time_bound: ClassVar[bool] = False
    # u_bound_from_V1: u = gamma_hat u0 + phi_hat sign(u0) with constant gamma_hat, phi_hat, and V1 does not
    # grow along the guaranteed solution, so sup |u| over {V1 <= V1(z0)} bounds what the law asks for.
    u_bound_from_V1: ClassVar[bool] = False
    # u_continuous: u is a continuous function of (z, the law's state) everywhere, so z_1^(r) = phi + gamma u
    # does not jump and a differentiator of order n > r - 1 may assume a bound on z_1^(n+1). False for any
    # law with a sign or a relay (even only at the origin, as the quasi-continuous law): the scenario loader
    # then refuses an observer of order n > r - 1 (Levant 2003: |f^(n+1)| <= L must hold).
    u_continuous: ClassVar[bool] = False

    r: int  # chain length the law controls

    @classmethod
    def all_params(cls) -> tuple[Param, ...]:
        return cls.base_params + cls.params

    @classmethod
    def from_params(cls, r: int, values: dict) -> "Law":
        """The law for chain length r from {param name: value} (every declared param, defaults filled).
        Raises ParameterError naming the parameter."""
        raise NotImplementedError

    @classmethod
    def bound_holds(cls, params: dict, phibar: float, gamma_m: float, gamma_M: float) -> bool:
        """Whether the law's time bound is a guarantee on a plant whose true bounds (chain units) are
        |phi| <= phibar and gamma_m <= gamma <= gamma_M; params: the law's own (LoopInfo.law_params).
        Only asked of a law with ``time_bound``, and only with a certificate."""
        return False

    @classmethod
    def ultimate_bound(cls, params: dict) -> dict | None:
        """Theorem 3's adaptation constants {kappa, delta, rate, eps} when the law has its ultimate
        bounds (limsup V1 <= Delta, liminf V1 <= eps), else None; params as for :meth:`bound_holds`."""
        return None

    @property
    def state_size(self) -> int:
        return 0

    def initial_state(self) -> np.ndarray:
        """The state at t = 0, shape (state_size,)."""
        return np.zeros(self.state_size)

    def evaluate(self, z, state) -> LawOutput:
        raise NotImplementedError

    def state_derivative(self, z, state, out: LawOutput) -> np.ndarray:
        return np.zeros(np.shape(state))

    def advance(self, z, state, out: LawOutput, h: float) -> np.ndarray:
        return np.asarray(state, dtype=float) + h * self.state_derivative(z, state, out)

    def for_period(self, h: float) -> "Law":
        """The law as run with control period h (s). A law whose discrete form depends on the period
        (an implicit discretization) returns a copy that knows it; the run loop calls this once."""
        return self

    def base_info(self) -> dict:
        """Parameters of the underlying controller (LoopInfo.hong), {} when the law has none."""
        return {}

    def param_values(self) -> dict:
        """The law's own parameter values (LoopInfo.law_params)."""
        return {p.name: getattr(self, p.name) for p in self.params}

    def native_params(self) -> dict:
        """The numbers of the law's C twin: {field of the kernel's law record (laws.h ft_law): a number or a
        sequence}, usually {"par": (...)} in the order laws.c reads them. Asked only when ``native_code`` is set."""
        return {}


# -- the registry ----------------------------------------------------------------------------------
LAWS: dict[str, type[Law]] = {}


def register_law(cls: type[Law]) -> type[Law]:
    """Class decorator: add ``cls`` to the registry under ``cls.name`` (the scenario loader and `ftstab list`
    read it from there). Each law owns its parameter table: two laws may use one key with two meanings."""
    if not (isinstance(cls.name, str) and cls.name.isidentifier()):
        raise TypeError(f"law class {cls.__name__} needs a name that is an identifier, got {cls.name!r}")
    if cls.name in LAWS and LAWS[cls.name] is not cls:
        raise TypeError(f"a law named {cls.name!r} is already registered ({LAWS[cls.name].__name__})")
    names = [p.name for p in cls.all_params()]
    if "law" in names:
        raise TypeError(f"law {cls.name!r}: 'law' names the law, it cannot be a parameter")
    if len(set(names)) != len(names):
        raise TypeError(f"law {cls.name!r}: a parameter is declared twice ({', '.join(names)})")
    LAWS[cls.name] = cls
    return cls


def unregister_law(name: str) -> None:
    """Remove a registered law (a test's toy law: global state put back)."""
    del LAWS[name]


def declared(name: str) -> type[Law] | None:
    """The registered law ``name`` (a log's LoopInfo.law), or None when this process does not know it
    (a log written with a plugin that is not loaded): nothing is then claimed for it."""
    return LAWS.get(name)


def law_class(name: str) -> type[Law]:
    try:
        return LAWS[name]
    except KeyError:
        raise ParameterError("law", "one of " + ", ".join(LAWS), name) from None
