"""huefringe: one-shot trapezoidal HSI fringe-projection profilometry."""

__version__ = "0.1.0"
