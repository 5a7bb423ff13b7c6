"""The causal graph G_M of the world model (thesis §4.3.1) on ``networkx.DiGraph``.

Admissibility (Eq. 4.30, footnote 15): the graph is acyclic, actions are roots
(deg^-(A_i) = 0), and no edge runs backwards in time (lag 0 -> lag 1).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import networkx as nx

from models.checks import check_edges, check_float, check_mapping, describe
from models.variables import Role, Variable, variable_name

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["CausalGraph"]

_FORMAT = "pal.causal_graph/1"


def _dot_escape(text: str) -> str:
    """``text`` for the inside of a DOT double-quoted string."""
    return text.replace("\\", "\\\\").replace('"', '\\"')


def _dot_id(name: str) -> str:
    """A variable name as a quoted DOT node id."""
    return f'"{_dot_escape(name)}"'


class CausalGraph:
    """A validated DAG over typed :class:`Variable` nodes.

    Parents are ordered by variable declaration order; that order fixes the layout of
    each mechanism's input vector ``concat(pa_i)``.

    Args:
        variables: the nodes, with unique names.
        edges: ``(parent, child)`` name pairs.
        confidence: optional ``(parent, child) -> c`` in [0, 1] for some edges, e.g. the
            posterior edge probability that structure learning assigns; it travels with
            the graph (JSON, :meth:`with_edges`) but is not part of its identity
            (:meth:`fingerprint`, ``==``).

    Raises:
        ValueError: on duplicate or unknown names, cycles, parents of an action,
            edges from lag 0 to lag 1, self-loops, a malformed ``lag_of``, or a
            confidence for a missing edge or outside [0, 1].
    """

    def __init__(
        self,
        variables: Sequence[Variable],
        edges: Iterable[tuple[str, str]] = (),
        confidence: Mapping[tuple[str, str], float] | None = None,
    ) -> None:
        if isinstance(variables, (str, bytes, Mapping)) or not isinstance(variables, Iterable):
            raise ValueError(f"variables must be a sequence of Variable, got {describe(variables)}")
        variables = list(variables)
        for v in variables:
            if not isinstance(v, Variable):
                raise ValueError(f"expected Variable instances, got {type(v).__name__}: {v!r}")
        names = [v.name for v in variables]
        seen: set[str] = set()
        for n in names:
            if n in seen:
                raise ValueError(f"duplicate variable name {n!r}")
            seen.add(n)
        self._variables: dict[str, Variable] = {v.name: v for v in variables}
        self._index = {n: i for i, n in enumerate(names)}
        g = nx.DiGraph()
        g.add_nodes_from(names)
        if isinstance(edges, (str, bytes, Mapping)) or not isinstance(edges, Iterable):
            raise ValueError(f"edges must be a sequence of (parent, child) pairs, got {describe(edges)}")
        for edge in edges:
            if isinstance(edge, (str, bytes)) or not isinstance(edge, Sequence) or len(edge) != 2:
                raise ValueError(f"edge {edge!r} is not a (parent, child) pair")
            parent, child = edge
            for end in (parent, child):
                if not isinstance(end, str):
                    raise ValueError(f"edge {edge!r} names {describe(end)}; expected variable names (str)")
                if end not in self._variables:
                    raise ValueError(
                        f"edge {parent!r} -> {child!r} names unknown variable {end!r}; known: {names}"
                    )
            if parent == child:
                raise ValueError(f"self-loop on {parent!r}; a variable cannot cause itself within a step")
            pv, cv = self._variables[parent], self._variables[child]
            if cv.role is Role.ACTION:
                raise ValueError(f"action {child!r} has parent {parent!r}; actions are roots (Eq. 4.30)")
            if pv.lag == 0 and cv.lag == 1:
                raise ValueError(f"edge {parent!r} (lag 0) -> {child!r} (lag 1) runs backwards in time")
            g.add_edge(parent, child)
        if not nx.is_directed_acyclic_graph(g):
            cycle = nx.find_cycle(g)
            path = " -> ".join([u for u, _ in cycle] + [cycle[0][0]])
            raise ValueError(f"graph has a cycle: {path}")
        for v in variables:
            if v.lag_of is None:
                continue
            if v.lag_of not in self._variables:
                raise ValueError(f"variable {v.name!r}: lag_of names unknown variable {v.lag_of!r}")
            src = self._variables[v.lag_of]
            if src.lag != 0 or src.dim != v.dim:
                raise ValueError(
                    f"variable {v.name!r}: lag_of {v.lag_of!r} must be a lag-0 variable of dim "
                    f"{v.dim}, got lag {src.lag}, dim {src.dim}"
                )
        self._confidence: dict[tuple[str, str], float] = {}
        for edge, value in dict(check_mapping("confidence", confidence, allow_none=True)).items():
            if (
                not isinstance(edge, tuple)
                or len(edge) != 2
                or not all(isinstance(e, str) for e in edge)
                or not g.has_edge(*edge)
            ):
                raise ValueError(f"confidence given for {edge!r}, which is not an edge of the graph")
            c = check_float(f"confidence of edge {edge[0]!r} -> {edge[1]!r}", value)
            if not 0.0 <= c <= 1.0:
                raise ValueError(
                    f"confidence of edge {edge[0]!r} -> {edge[1]!r} is {value!r}, expected [0, 1]"
                )
            self._confidence[edge] = c
            g.edges[edge]["confidence"] = c
        self._g = g
        self._order = tuple(nx.lexicographical_topological_sort(g, key=self._index.__getitem__))
        self._parents = {n: tuple(sorted(g.predecessors(n), key=self._index.__getitem__)) for n in names}

    @classmethod
    def from_edges(
        cls,
        edges: Iterable[tuple[Any, Any]],
        nodes: Iterable[Any] = (),
        *,
        roles: Mapping[Any, Role | str] | None = None,
        confidence: Mapping[tuple[Any, Any], float] | None = None,
    ) -> CausalGraph:
        """A graph from ``(parent, child)`` label pairs; every variable an observed scalar by default.

        Labels are free text, named by the rule of :func:`models.variables.variable_name`
        (a valid name is kept; ``" age"`` becomes ``"%20age"``), so the graph's names are
        those :func:`models.tables.as_table` gives the same table's columns.

        Args:
            edges: ``(parent, child)`` pairs of labels.
            nodes: further labels (variables without edges), or :class:`Variable` objects,
                which are taken as they are (use them for actions, which need bounds, and
                for ``dim`` > 1).
            roles: label -> role for the variables made here (default ``"observed"``).
            confidence: optional ``(parent, child)`` label pair -> confidence in [0, 1].

        Raises:
            ValueError: malformed pairs or labels, roles for unknown labels, and everything
                :class:`CausalGraph` refuses (cycles, parents of actions, ...).
        """
        if isinstance(edges, (str, bytes, Mapping)) or not isinstance(edges, Iterable):
            raise ValueError(f"edges must be a sequence of (parent, child) pairs, got {describe(edges)}")
        pairs = []
        for edge in edges:
            if isinstance(edge, (str, bytes)) or not isinstance(edge, Sequence) or len(edge) != 2:
                raise ValueError(f"edge {edge!r} is not a (parent, child) pair")
            pairs.append((variable_name(edge[0]), variable_name(edge[1])))
        given = {}
        labels: list[str] = []
        for node in nodes:
            if isinstance(node, Variable):
                given[node.name] = node
                labels.append(node.name)
            else:
                labels.append(variable_name(node))
        labels += [n for e in pairs for n in e]
        role_of = {
            variable_name(k): v for k, v in dict(check_mapping("roles", roles, allow_none=True)).items()
        }
        names = list(dict.fromkeys(labels))
        unknown = sorted(set(role_of) - set(names))
        if unknown:
            raise ValueError(f"roles name {unknown}, which are in no edge or node; names: {names}")
        variables = [given.get(n) or Variable(n, role_of.get(n, Role.OBSERVED)) for n in names]
        conf = {
            (variable_name(p), variable_name(c)): v
            for (p, c), v in dict(check_mapping("confidence", confidence, allow_none=True)).items()
        }
        return cls(variables, pairs, conf or None)

    # ------------------------------------------------------------------ queries
    @property
    def nx(self) -> nx.DiGraph:
        """A copy of the underlying ``networkx.DiGraph``."""
        return self._g.copy()

    @property
    def variables(self) -> dict[str, Variable]:
        """Name -> Variable, in declaration order."""
        return dict(self._variables)

    @property
    def names(self) -> tuple[str, ...]:
        """Variable names in declaration order."""
        return tuple(self._variables)

    @property
    def edges(self) -> tuple[tuple[str, str], ...]:
        """Edges sorted by (child, parent) declaration order."""
        return tuple((p, c) for c in self.names for p in self._parents[c])

    @property
    def confidence(self) -> dict[tuple[str, str], float]:
        """Edge -> confidence in [0, 1] for the edges that carry one (others are absent)."""
        return dict(self._confidence)

    def edge_confidence(self, parent: str, child: str) -> float | None:
        """The confidence of ``parent -> child``, or None if it carries none.

        Raises:
            ValueError: the edge is not in the graph.
        """
        if not (isinstance(parent, str) and isinstance(child, str) and self._g.has_edge(parent, child)):
            raise ValueError(f"{parent!r} -> {child!r} is not an edge of the graph")
        return self._confidence.get((parent, child))

    def with_confidence(self, confidence: Mapping[tuple[str, str], float]) -> CausalGraph:
        """The same graph with these edge confidences (replacing any it had)."""
        return CausalGraph(list(self._variables.values()), self.edges, confidence)

    def __getitem__(self, name: str) -> Variable:
        return self._variables[self.check_name(name)]

    def __contains__(self, name: object) -> bool:
        return name in self._variables

    def __len__(self) -> int:
        return len(self._variables)

    def check_name(self, name: str, what: str = "variable") -> str:
        """Return ``name`` or raise a ValueError listing the known names."""
        if not isinstance(name, str):
            raise ValueError(
                f"{what} name must be a str, got {describe(name)}; known variables: {list(self._variables)}"
            )
        if name not in self._variables:
            raise ValueError(f"unknown {what} {name!r}; known variables: {list(self._variables)}")
        return name

    def parents(self, name: str) -> tuple[str, ...]:
        """pa(X_i), in declaration order."""
        return self._parents[self.check_name(name)]

    def children(self, name: str) -> tuple[str, ...]:
        """Direct children, in declaration order."""
        return tuple(sorted(self._g.successors(self.check_name(name)), key=self._index.__getitem__))

    def ancestors(self, name: str) -> set[str]:
        """Every variable with a directed path to ``name``."""
        return set(nx.ancestors(self._g, self.check_name(name)))

    def descendants(self, name: str) -> set[str]:
        """Every variable with a directed path from ``name``."""
        return set(nx.descendants(self._g, self.check_name(name)))

    def topological_order(self) -> tuple[str, ...]:
        """A deterministic topological order (ties broken by declaration order)."""
        return self._order

    def is_root(self, name: str) -> bool:
        """True if ``name`` has no parents (an action or an exogenous/lag-1 input)."""
        return not self._parents[self.check_name(name)]

    @property
    def roots(self) -> tuple[str, ...]:
        """Variables without parents, in topological order."""
        return tuple(n for n in self._order if not self._parents[n])

    @property
    def non_roots(self) -> tuple[str, ...]:
        """Variables with a mechanism f_i, in topological order."""
        return tuple(n for n in self._order if self._parents[n])

    def by_role(self, role: Role | str) -> tuple[str, ...]:
        """Names of the variables with this role, in declaration order."""
        if not isinstance(role, str) or role not in [r.value for r in Role]:
            raise ValueError(f"role {role!r} unknown; expected one of {[r.value for r in Role]}")
        role = Role(role)
        return tuple(n for n, v in self._variables.items() if v.role is role)

    @property
    def actions(self) -> tuple[str, ...]:
        """Action variables V_act, in declaration order."""
        return self.by_role(Role.ACTION)

    @property
    def lagged(self) -> dict[str, str]:
        """Lag-1 slot -> the lag-0 variable that fills it at the next step."""
        return {n: v.lag_of for n, v in self._variables.items() if v.lag_of is not None}

    # ------------------------------------------------------------------ editing
    def with_edges(
        self, add: Iterable[tuple[str, str]] = (), remove: Iterable[tuple[str, str]] = ()
    ) -> CausalGraph:
        """A new graph with edges added and removed (validated as a whole)."""
        add = check_edges("add", add)
        remove = set(check_edges("remove", remove))
        missing = remove - set(self.edges)
        if missing:
            raise ValueError(f"cannot remove edges {sorted(missing)}: not in the graph")
        edges = [e for e in self.edges if e not in remove]
        edges += [e for e in add if e not in edges]
        kept = {e: c for e, c in self._confidence.items() if e not in remove}
        return CausalGraph(list(self._variables.values()), edges, kept)

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible description: format tag, variables, edges (and edge confidences if any)."""
        out: dict[str, Any] = {
            "format": _FORMAT,
            "variables": [v.to_dict() for v in self._variables.values()],
            "edges": [list(e) for e in self.edges],
        }
        if self._confidence:
            out["confidence"] = [
                [p, c, self._confidence[p, c]] for p, c in self.edges if (p, c) in self._confidence
            ]
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> CausalGraph:
        """Inverse of :meth:`to_dict`.

        Raises:
            ValueError: another format, missing or malformed ``variables``/``edges``/``confidence``.
        """
        if not isinstance(data, Mapping) or data.get("format") != _FORMAT:
            got = data.get("format") if isinstance(data, Mapping) else type(data).__name__
            raise ValueError(f"not a causal graph description: format {got!r}, expected {_FORMAT!r}")
        for key in ("variables", "edges"):
            if key not in data:
                raise ValueError(f"causal graph description has no {key!r} entry")
            if isinstance(data[key], (str, Mapping)) or not isinstance(data[key], Sequence):
                raise ValueError(f"causal graph {key!r} must be a list, got {describe(data[key])}")
        confidence = {}
        entries = data.get("confidence", [])
        if isinstance(entries, (str, Mapping)) or not isinstance(entries, Sequence):
            raise ValueError(f"causal graph 'confidence' must be a list, got {describe(entries)}")
        for entry in entries:
            if isinstance(entry, str) or not isinstance(entry, Sequence) or len(entry) != 3:
                raise ValueError(f"confidence entry {entry!r} is not [parent, child, value]")
            confidence[entry[0], entry[1]] = entry[2]
        for v in data["variables"]:
            if not isinstance(v, Mapping):
                raise ValueError(f"causal graph variable entry {v!r} is not a mapping")
        return cls(
            [Variable.from_dict(v) for v in data["variables"]],
            [tuple(e) if isinstance(e, list) else e for e in data["edges"]],
            confidence,
        )

    def to_json(self, indent: int | None = 2) -> str:
        """:meth:`to_dict` as JSON text (keys sorted)."""
        return json.dumps(self.to_dict(), indent=indent, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> CausalGraph:
        """Parse :meth:`to_json` output."""
        if not isinstance(text, (str, bytes)):
            raise ValueError(f"causal graph JSON must be a str, got {describe(text)}")
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            raise ValueError(f"causal graph JSON is malformed: {err}") from None
        return cls.from_dict(data)

    def fingerprint(self) -> str:
        """SHA-256 of the canonical JSON (descriptions excluded); equal graphs share it."""
        d = self.to_dict()
        d.pop("confidence", None)
        for v in d["variables"]:
            v.pop("description")
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()

    def __eq__(self, other: object) -> bool:
        return isinstance(other, CausalGraph) and self.fingerprint() == other.fingerprint()

    def __hash__(self) -> int:
        return hash(self.fingerprint())

    def __repr__(self) -> str:
        return (
            f"CausalGraph({len(self)} variables, {self._g.number_of_edges()} edges: "
            + ", ".join(f"{p}->{c}" for p, c in self.edges)
            + ")"
        )

    def to_dot(self) -> str:
        """Graphviz DOT text; shape encodes the role, dashed borders mark lag-1 slots.

        Node ids and labels are quoted DOT strings (quotes and backslashes escaped), so names with
        ``:``, ``/``, ``-``, spaces or quotes stay one node.
        """
        shapes = {Role.ACTION: "box", Role.OBSERVED: "ellipse", Role.LATENT: "ellipse"}
        fills = {Role.ACTION: "#f4c06b", Role.OBSERVED: "#9cc3e6", Role.LATENT: "#ffffff"}
        lines = ["digraph world_model {", "  rankdir=LR;"]
        for n, v in self._variables.items():
            style = "filled,dashed" if v.lag else "filled"
            label = _dot_escape(n) if not v.unit else f"{_dot_escape(n)}\\n[{_dot_escape(v.unit)}]"
            lines.append(
                f'  {_dot_id(n)} [label="{label}", shape={shapes[v.role]}, style="{style}", '
                f'fillcolor="{fills[v.role]}"];'
            )
        lines += [f"  {_dot_id(p)} -> {_dot_id(c)};" for p, c in self.edges]
        lines.append("}")
        return "\n".join(lines) + "\n"

    def plot(self, ax: Any = None, edge_labels: Mapping[tuple[str, str], str] | None = None) -> Figure:
        """Draw the graph in topological layers; returns the matplotlib Figure.

        Without ``edge_labels``, edges that carry a confidence are labelled with it.
        """
        import matplotlib.pyplot as plt  # plotting is optional; imported on use

        if ax is None:
            fig, ax = plt.subplots(figsize=(1.8 + 1.6 * len(list(nx.topological_generations(self._g))), 3.2))
        else:
            fig = ax.figure
        g = self._g.copy()
        for layer, nodes in enumerate(nx.topological_generations(g)):
            for node in nodes:
                g.nodes[node]["layer"] = layer
        pos = nx.multipartite_layout(g, subset_key="layer")
        colors = {Role.ACTION: "#f4c06b", Role.OBSERVED: "#9cc3e6", Role.LATENT: "#e8e8e8"}
        nx.draw_networkx_nodes(
            g,
            pos,
            ax=ax,
            node_color=[colors[self._variables[n].role] for n in g.nodes],
            node_size=1400,
            edgecolors="#333333",
        )
        # names are drawn as plain text: a "$" would otherwise start matplotlib mathtext
        labels = {n: n.replace("$", r"\$") for n in g.nodes}
        nx.draw_networkx_labels(g, pos, labels=labels, ax=ax, font_size=8)
        # edges that skip a layer are drawn curved so they do not hide behind the others
        for bend, keep in ((0.0, lambda d: d <= 1), (0.25, lambda d: d > 1)):
            edges = [(u, v) for u, v in g.edges if keep(g.nodes[v]["layer"] - g.nodes[u]["layer"])]
            nx.draw_networkx_edges(
                g,
                pos,
                edgelist=edges,
                ax=ax,
                arrowsize=14,
                node_size=1400,
                connectionstyle=f"arc3,rad={bend}",
            )
        if edge_labels is None and self._confidence:
            edge_labels = {e: f"{c:.2f}" for e, c in self._confidence.items()}
        if edge_labels:
            labels = dict(edge_labels)
            for bend, keep in ((0.0, lambda d: d <= 1), (0.25, lambda d: d > 1)):
                part = {
                    e: t for e, t in labels.items() if keep(g.nodes[e[1]]["layer"] - g.nodes[e[0]]["layer"])
                }
                if part:
                    nx.draw_networkx_edge_labels(
                        g, pos, edge_labels=part, ax=ax, font_size=7, connectionstyle=f"arc3,rad={bend}"
                    )
        handles = [
            plt.Line2D([], [], marker="o", ls="", color=c, markersize=10, label=r.value)
            for r, c in colors.items()
        ]
        ax.legend(handles=handles, loc="best", fontsize=7, frameon=False)
        ax.margins(x=0.12, y=0.22)
        ax.set_axis_off()
        fig.tight_layout()
        return fig
