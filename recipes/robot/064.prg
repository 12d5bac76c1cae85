program 64
# DROOG_PIJP: dry run of the pipe seam.
move approach 8
weld pipe_seam 40
move home 12
