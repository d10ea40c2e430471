"""The primitive kinds a scene can hold, as the integers the kernels branch on."""

TRIANGLE = 0
SPHERE = 1
