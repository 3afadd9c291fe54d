"""What every CLI shares: clean one-line errors and exit codes.

Exit codes: 0 success, 2 bad input or config, 1 internal error, 130 interrupted
(after a checkpoint was written).
"""

from __future__ import annotations

import sys
from typing import Callable


def run_cli(main: Callable[[], object]) -> None:
    """Run ``main`` and turn expected failures into one-line messages and exit codes."""
    from pydantic import ValidationError

    from ..errors import CheckpointError, DataError

    try:
        main()
    except (DataError, CheckpointError) as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    except ValidationError as e:
        errs = "; ".join(
            f"{'.'.join(str(p) for p in err['loc']) or 'config'}: {err['msg']}" for err in e.errors()
        )
        print(f"error: invalid config: {errs}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        sys.exit(130)
    except Exception as e:
        from ..trainer import TrainingInterrupted

        if isinstance(e, TrainingInterrupted):
            print(f"stopped: {e}", file=sys.stderr)
            sys.exit(130)
        raise
