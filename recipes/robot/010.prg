program 10
# Reference run: every axis to its mark, then home.
move reference 20
move home 10
