from bgap.runner.numerics import command

main = command("bgap.experiments.bench")
if __name__ == "__main__":
    main()
