"""IMC I/O: link to DUNE vehicles, logs, SITL."""
