"""``artifem bench reduced`` (artifem.bench_reduced): the operation count of generated C,
and the command on the quick tongue study's training (tests/conftest.py).

(1) count_flops on a source of known work: binary operators and math calls count one,
    unary minus and array indices none, a statement in a loop once per iteration, the
    function ends at its closing brace;
(2) the command writes every part of the step with its time and work, the kernels'
    counts from their generated code, and parts that add up to the step.
"""

import json

import pytest

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from mpi4py import MPI

from artifem.bench_reduced import count_flops
from artifem.cli import main

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="reduced bodies are serial")

SOURCE = """
static const double FE[4] = {-1.0, 1.0, 0.0, 0.0};
void tabulate_tensor_expression_x(double* restrict A, const double* restrict w)
{
// a comment = 1 + 2
static const double T[1][2] = {{1.0, 2.0}};
double g = 0.0;
for (int ic = 0; ic < 4; ++ic)
{
  g += w[(ic) * 3 + 1] * FE[ic];
}
double a = -g;
double b = a * g + w[2 * 5] * 1e-05;
double c = pow(b, 2.0) / (a - b);
bool d = c <= 1.0;
for (int iq = 0; iq < 1; ++iq)
{
  A[55 * iq + 0] += d ? c : -a;
}
}
double not_counted = 1.0 + 2.0;
"""


def test_count_flops_counts_the_arithmetic_of_the_kernel():
    # loop: 4 x (+= and *) = 8; a = -g: 0; b: *, + and * = 3 (1e-05 a literal); c: pow,
    # / and - = 3;
    # d: a comparison, 0; A += ...: 1
    assert count_flops(SOURCE) == 8 + 0 + 3 + 3 + 0 + 1


def test_bench_reduced_on_the_quick_training(quick_tongue_study, tmp_path):
    out = tmp_path / "reduced.json"
    assert (
        main(
            [
                "bench",
                "reduced",
                "--quick",
                "--incompressibility",
                "hard",
                "--cache",
                str(quick_tongue_study / "cache"),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    report = json.loads(out.read_text())
    (case,) = report["cases"]
    assert (case["r"], case["m"], case["incompressibility"]) == (8, 120, "hard")
    assert case["training_runs"] == 11  # the quick study's, from its cache
    assert set(case["parts"]) == {"stresses", "tangent", "force", "kinematics", "rest"}
    for part in case["parts"].values():
        assert part["ms"] >= 0 and part["flops"] > 0
    kernels = case["kernels"]
    assert sum(k["points"] for k in kernels) == 120
    assert all(k["flops_per_point"] > 200 for k in kernels)
    assert case["parts"]["stresses"]["flops"] == sum(
        k["points"] * k["flops_per_point"] for k in kernels
    )
    # the dense parts' textbook counts for r = 8, m = 120 (a multiply-add is 2): the tangent
    # U^T B^T C B U over the points, the force and kinematics products, the r x r solve
    r, m = 8, 120
    dense = {
        "tangent": 81 * m + 2 * 81 * r * m + 2 * 9 * m * r * r,
        "force": 2 * 9 * m * r,
        "kinematics": 2 * 9 * m * r,
        "rest": round(2 / 3 * r**3),
    }
    assert {k: case["parts"][k]["flops"] for k in dense} == dense
    assert case["flops_per_step"] == sum(p["flops"] for p in case["parts"].values())
    assert case["ms_per_step"] > 0 and case["met"] is None
