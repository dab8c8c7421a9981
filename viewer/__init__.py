"""The viser scene and controls (reads snapshots, calls the engine). Built in a later issue."""
