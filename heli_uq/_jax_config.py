"""JAX settings made before any array is created (imported first by ``heli_uq``).

* ``jax_enable_x64``: float64 throughout.
* Arrays a jitted function closes over (a record's voltages and angles, the prior
  location of its initial angles) are passed to the compiled program as arguments
  instead of being embedded in it (``JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS``, JAX's coming
  default, and ``JAX_EMBEDDED_CONSTANTS_MAX_BYTES=0``; see
  https://docs.jax.dev/en/latest/internals/constants.html).  Records of one length then
  share compiled programs: a second record, an SBC replicate, a discovery run on another
  record or a test reads them from the persistent compilation cache
  (:func:`heli_uq.executor.use_compilation_cache`) instead of compiling them again, and
  a program without a record embedded in it compiles faster.  JAX reads the first
  setting when it is imported, so it is set here only where JAX is not imported yet
  (a user's own value is kept); otherwise records are embedded as before, which changes
  compile times, not results.
* The warning JAX gives when a persistent cache entry cannot be read is silenced
  (:data:`CACHE_READ_WARNING`): without a cache size limit JAX writes an entry in place, so
  a process that reads it while another writes it finds it empty or cut short; JAX then
  compiles the program again, which is the right result, and the warning says nothing a
  user can act on (seen in CI, where the two test workers compile the same programs).
"""

import os
import sys
import warnings

#: The environment that makes records arguments of the compiled programs (JAX's own
#: defaults, ``"false"`` and ``"32"``, embed them).
RECORDS_AS_ARGUMENTS = {"JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS": "true", "JAX_EMBEDDED_CONSTANTS_MAX_BYTES": "0"}

if "jax" not in sys.modules:
    for key, value in RECORDS_AS_ARGUMENTS.items():
        os.environ.setdefault(key, value)

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

#: The start of JAX's warning for a persistent cache entry it cannot read (it compiles again).
CACHE_READ_WARNING = "Error reading persistent compilation cache entry"
warnings.filterwarnings("ignore", message=CACHE_READ_WARNING, category=UserWarning)
