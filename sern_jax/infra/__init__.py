"""Infrastructure: run directories and atomic writes (``io``), Ray (``distributed``), device
meshes (``sharding``), timing (``timing``) and the flag checks every command shares
(``validate``). Threads, files and environment variables live here and in the drivers."""
