"""Plumbing every package uses: one-line user errors, outputs written whole or not at all and never over an
input, one writer per output (locks), temporary names kept out of messages, progress reports, the words
for a missing path. Standard library only.
"""
