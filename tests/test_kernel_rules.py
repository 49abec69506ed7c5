"""Rules every Taichi kernel of the package keeps for the GPU archs, checked
on the source (no GPU, no Taichi needed).

Taichi 1.7.4's CUDA backend keeps a kernel-scope local that several of the
kernel's offloaded tasks use in a global temporaries buffer, and a vector or
matrix of f64 there can land off its alignment: reading it inside a parallel
loop faults with ``CUDA_ERROR_MISALIGNED_ADDRESS`` (seen on an H200: the
flow's ``predict`` with its gravity vector built before the loop, BiCGSTAB's
several-column alpha and beta; docs/arch.md).  So no kernel may build a
vector or matrix at kernel scope and read it inside a later loop: build it
inside the loop, or pass it through an ndarray.  Reductions (``acc += ...``
into a kernel-scope vector) are not reads and ran correctly there.  The
check reads kernels' own bodies, not the ``ti.func`` bodies they inline.
"""
import ast
import pathlib

ROOT = pathlib.Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "taichi_hh"

#: calls that make a vector or matrix (``zeros(cols)``: a vector for several
#: columns, :mod:`taichi_hh.linalg.columns`)
VECTOR_MAKERS = ("ti.Vector", "ti.Matrix", "ti.math.vec", "ti.math.mat", "ti.math.ivec",
                 "zeros(", "lanes.pack", "lanes_mod.pack")


def _is_kernel(fn: ast.FunctionDef) -> bool:
    return any(ast.unparse(d) in ("ti.kernel", "taichi.kernel") for d in fn.decorator_list)


def _makes_vector(value: ast.AST, vectors: set) -> bool:
    text = ast.unparse(value)
    if any(maker in text for maker in VECTOR_MAKERS):
        return True
    return any(isinstance(n, ast.Name) and n.id in vectors for n in ast.walk(value))


def _loads(node: ast.AST) -> set:
    return {n.id for n in ast.walk(node) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)}


def kernel_vector_reads(source: str) -> list:
    """(kernel, name, line) for each kernel-scope vector read inside a later
    top-level loop of a kernel in ``source``."""
    found = []
    for fn in ast.walk(ast.parse(source)):
        if not (isinstance(fn, ast.FunctionDef) and _is_kernel(fn)):
            continue
        vectors: set = set()

        def visit(statements):
            for st in statements:
                if isinstance(st, (ast.For, ast.While)):
                    for name in sorted(_loads(st) & vectors):
                        found.append((fn.name, name, st.lineno))
                elif isinstance(st, ast.If):          # ti.static branches stay at kernel scope
                    visit(st.body)
                    visit(st.orelse)
                elif isinstance(st, (ast.Assign, ast.AnnAssign)):
                    targets = st.targets if isinstance(st, ast.Assign) else [st.target]
                    # the names bound (``x = ...``, ``a, b = ...``), not ``arr[k] = ...``
                    names = {n.id for t in targets
                             for n in ([t] if isinstance(t, ast.Name) else
                                       t.elts if isinstance(t, ast.Tuple) else [])
                             if isinstance(n, ast.Name)}
                    if st.value is not None and _makes_vector(st.value, vectors):
                        vectors.update(names)
                    else:
                        vectors.difference_update(names)
        visit(fn.body)
    return found


def test_the_rule_finds_what_faulted_on_cuda():
    """The check itself: the shape that faulted is found, its fixes are not."""
    faulted = '''
@ti.kernel
def predict(n: ti.i32, gx: float, gy: float, w: ti.types.ndarray()):
    g = ti.Vector([gx, gy])
    for i in range(n):
        w[i] = g
'''
    fixed = '''
@ti.kernel
def predict(n: ti.i32, gx: float, gy: float, w: ti.types.ndarray()) -> float:
    acc = zeros(2)
    for i in range(n):
        g = ti.Vector([gx, gy])
        w[i] = g
        acc += g
    return acc[0]
'''
    assert kernel_vector_reads(faulted) == [("predict", "g", 5)]
    assert kernel_vector_reads(fixed) == []


def test_no_kernel_reads_a_kernel_scope_vector_in_a_loop():
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for kernel, name, line in kernel_vector_reads(path.read_text()):
            offenders.append(f"{path.relative_to(ROOT)}:{line} {kernel}: {name}")
    assert not offenders, "kernel-scope vectors read by a loop (fault on CUDA):\n" + \
        "\n".join(offenders)
