"""The paper's experiments, in simulation: Fig. 2 (`fig2`, on `synthetic` problems) and Tables I/II
(`robots`), and the `seeds` summaries of the reproduction scripts. Not part of the library: the
scripts beside this folder run them, and the tests and notebooks import them from here."""
