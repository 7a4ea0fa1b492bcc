"""How long a process waits for another one compiling the same form (DOLFINx's JIT).

DOLFINx compiles each form once into a cache shared by every process of the user. A
process that finds another one compiling the same form waits for it, up to the JIT option
``timeout`` (10 s by default), then raises "JIT compilation timed out". On a fresh cache
that wait is routine, not a failure: two commands run at once, a test worker beside an
``mpiexec`` run, two study jobs. The tongue's forms take 12 s to compile on a quiet
2-core machine and more on a busy one, so the second process stopped. Importing this
module raises the default to :data:`COMPILE_WAIT_S`; a user's own
``dolfinx_jit_options.json`` still takes priority. A compile that fails removes its file,
so only a process killed while compiling leaves one to wait for (the error then names
it).
"""

import artifem  # noqa: F401  (MPI before dolfinx)
from dolfinx import jit

#: seconds a process waits for another one's compile of the same form
COMPILE_WAIT_S = 300

_default, _help = jit.DOLFINX_DEFAULT_JIT_OPTIONS["timeout"]
jit.DOLFINX_DEFAULT_JIT_OPTIONS["timeout"] = (max(_default, COMPILE_WAIT_S), _help)
