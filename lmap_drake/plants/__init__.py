"""Plant models: fruit meshes, the plant scene added to the station."""
