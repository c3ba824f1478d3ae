from bgap.runner.numerics import command

main = command("bgap.experiments.sweep")
if __name__ == "__main__":
    main()
