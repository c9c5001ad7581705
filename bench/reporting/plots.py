"""Pictures of cases and deformation fields (matplotlib), and VTK export (meshio)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.tri as mtri  # noqa: E402
import meshio  # noqa: E402
import numpy as np  # noqa: E402

from fixbench.cases.problem import Problem  # noqa: E402


def outline(ax, problem: Problem, lw: float = 1.2) -> None:
    """The part's outline and holes in black, in millimetres."""
    poly = problem.spec.polygon
    for ring in (poly.exterior, *poly.interiors):
        x, y = np.asarray(ring.coords).T * 1e3
        ax.plot(x, y, color="black", lw=lw)


def candidate_groups(problem: Problem) -> list[tuple[str, np.ndarray]]:
    """The fixture candidates of each robot with its legend label: the robot's region name where the
    case names its regions (``[[agents.regions]]``), else ``robot i``, and its candidate count."""
    regions = [name for name, _ in problem.spec.agent_regions]
    return [(f"{regions[a] if regions else f'robot {a}'}: {len(idx)} candidates", idx)
            for a, idx in enumerate(problem.candidate_sets)]


def case_figure(problem: Problem):
    """Part, mesh, thickness regions, fixture candidates coloured by robot, supports and task load
    points; the legend,
    beside the part (it hides no candidate), lists each robot's candidates (:func:`candidate_groups`)."""
    model = problem.model
    fig, ax = plt.subplots(figsize=(9.5, 7))
    p = model.mesh.p * 1e3
    ax.triplot(mtri.Triangulation(p[0], p[1], model.mesh.t.T), color="0.8", lw=0.3)
    outline(ax, problem)
    for region in problem.spec.regions:  # thickness regions, shaded, with their thickness
        for k, piece in enumerate(getattr(region.polygon, "geoms", [region.polygon])):
            x, y = np.asarray(piece.exterior.coords).T * 1e3
            ax.fill(x, y, color="tab:olive", alpha=0.25, lw=0,
                    label=f"{region.name}: {region.thickness * 1e3:.3g} mm" if k == 0 else None)
    colors = plt.get_cmap("tab10")
    for a, (label, idx) in enumerate(candidate_groups(problem)):
        c = problem.candidates[idx] * 1e3
        ax.scatter(c[:, 0], c[:, 1], s=4, color=colors(a % 10), label=label)
    sup_pts = []
    for name in model.active:
        fs = model.fields[name]
        nodes = np.flatnonzero(np.isin(fs.basis.nodal_dofs[0], fs.fixed))
        sup_pts.append(model.mesh.p[:, nodes])
    if sup_pts:
        held = np.hstack(sup_pts) * 1e3
        ax.scatter(held[0], held[1], marker="s", s=6, color="black", label="base support")
    at = np.array([ld.at for t in problem.tasks for ld in t.loads if ld.at is not None])
    if len(at):
        ax.scatter(at[:, 0] * 1e3, at[:, 1] * 1e3, marker="x", s=10, color="red", label="task loads")
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(f"{problem.name}: {problem.spec.material.name}, {model.mesh.t.shape[1]} elements, "
                 f"{len(problem.candidates)} candidates"
                 + (f" ({problem.spec.candidates_dropped} grid points off the part dropped)"
                    if problem.spec.candidates_dropped else "")
                 + f", {problem.n_tasks} tasks", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, markerscale=2)
    return fig


def show_case(problem: Problem, out: Path) -> Path:
    """:func:`case_figure` as a PNG at ``out``."""
    return save_png(case_figure(problem), out)


def field_plot(problem: Problem, task: int, layout, out: Path) -> Path:
    """Contour of the deformation magnitude |u| for one layout (direct solve, full field)."""
    model = problem.model
    vals = model.nodal(problem.solve_direct(task, layout))
    mag = np.sqrt(vals["ux"] ** 2 + vals["uy"] ** 2 + vals["w"] ** 2) * 1e6
    p = model.mesh.p * 1e3
    fig, ax = plt.subplots(figsize=(7, 7))
    tc = ax.tricontourf(mtri.Triangulation(p[0], p[1], model.mesh.t.T), mag, levels=30, cmap="viridis")
    fig.colorbar(tc, ax=ax, label="|u| (um)")
    outline(ax, problem)
    if layout is not None:  # None: the free response, no fixtures
        c = problem.pad_xy(layout) * 1e3
        ax.scatter(c[:, 0], c[:, 1], color="red", marker="o", s=30, label="fixtures")
    at = [ld.at for ld in problem.tasks[task].loads if ld.at is not None]
    if at:
        at = np.array(at) * 1e3
        ax.scatter(at[:, 0], at[:, 1], color="white", marker="x", s=40, label="load")
    ax.set_aspect("equal")
    ax.set_title(f"{problem.name}, task {task}: max |u| at nodes {mag.max():.3g} um", fontsize=9)
    ax.legend(fontsize=7)
    return save_png(fig, out)


def write_vtk(problem: Problem, task: int, layout, out: Path) -> Path:
    """The displacement field at the mesh vertices as a VTU file for ParaView."""
    model = problem.model
    vals = model.nodal(problem.solve_direct(task, layout))
    points = np.column_stack([model.mesh.p.T, np.zeros(model.mesh.p.shape[1])])
    disp = np.column_stack([vals["ux"], vals["uy"], vals["w"]])
    mesh = meshio.Mesh(points, [("triangle", model.mesh.t.T)],
                       point_data={"displacement": disp, "magnitude": np.linalg.norm(disp, axis=1)})
    out.parent.mkdir(parents=True, exist_ok=True)
    mesh.write(out)
    return out


def anytime_plot(result, out: Path) -> Path:
    """Best max deformation so far against samples spent, one line per task (log x)."""
    fig, ax = plt.subplots(figsize=(6, 4))
    trace = result.trace
    for task in np.unique(trace[:, 0])[:20]:
        rows = trace[trace[:, 0] == task]
        ax.step(rows[:, 1], rows[:, 3] * 1e6, where="post", lw=0.8,
                label="shared (worst task)" if task < 0 else None)
    ax.set_xscale("log")
    ax.set_xlabel("samples spent on the task")
    ax.set_ylabel("best max |u| so far (um)")
    ax.set_title(f"{result.planner} on {result.case} ({result.mode}, seed {result.seed})", fontsize=9)
    return save_png(fig, out)


def save_png(fig, out: Path) -> Path:
    """``fig`` as a PNG at ``out`` (its folder made), then closed; laid out tightly unless it has a
    layout engine of its own (a constrained-layout figure of several panels)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    if fig.get_layout_engine() is None:
        fig.tight_layout()
    fig.savefig(out, dpi=130)
    plt.close(fig)
    return out
