"""The method of Jefferies, Cosgrove, Baker & Yeap: pure computation, no I/O, no threads."""
