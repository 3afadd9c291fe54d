"""``python -m splat_framework.sweep SPEC.json THREADS``: one run of the local backend."""

from .worker import worker_main

worker_main()
