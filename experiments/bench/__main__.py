from experiments.bench.suite import main

main()
