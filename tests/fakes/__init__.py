"""One shared fake per seam: tests build on these instead of one-off doubles."""
