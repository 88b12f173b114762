"""The one way a part that runs (a broker, a client, a simulated fleet, a whole local system) is
used as a context manager: ``with part:`` starts it and stops it on the way out."""

from __future__ import annotations

from typing import Self


class StartStop:
    """``__enter__`` is ``start()`` (which returns the part), ``__exit__`` is ``stop()``."""

    def start(self) -> Self:
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
